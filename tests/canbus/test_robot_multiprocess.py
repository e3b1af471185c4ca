"""The example robot end to end: ``skin sim run probe.toml --robot host.toml`` serves the
probe's presses on the robot's patches, ``skin run host.toml --contacts`` shows contacts
on the links, a press across two patches as one contact resting on both; two processes on
udp_multicast."""

from __future__ import annotations

import signal
import sys
from pathlib import Path

from tests.support.rigs.children import spawn
from tests.support.rigs.ports import udp_bus

SKIN = [sys.executable, "-m", "skin.cli"]
ROBOT = Path(__file__).resolve().parents[2] / "examples" / "robot"


def test_skin_run_shows_the_probe_scenes_contacts_on_the_robots_links() -> None:
    channel, port = udp_bus()
    bus = ["-i", "udp_multicast", "-c", channel, "--bus-kwargs", f"port={port}"]
    sim = spawn([*SKIN, "sim", "run", str(ROBOT / "probe.toml"), "--robot",
                 str(ROBOT / "host.toml"), *bus])
    host = None
    try:
        host = spawn([*SKIN, "run", str(ROBOT / "host.toml"), "--contacts", *bus])
        host.wait_for("contact on forearm (patches 1+2)", timeout=90)
        host.wait_for("contact on palm (patches 3+4)", timeout=90)
        host.wait_for("contact on palm (patches 3)", timeout=90)
    finally:
        for child in (host, sim):
            if child is not None:
                child.stop(signal.SIGTERM)
    out = host.output()
    assert "contact on upper_arm" not in out
