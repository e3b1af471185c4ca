"""A robot's own CANopen master in another process produces SYNC and tares a patch by SDO;
`skin run` with ``sync = "external"`` and its bus in the config's [bus] table, and
`skin sim run -i udp_multicast` without -c, find each other on the commands' default group.
"""

# mypy: disable-error-code="no-untyped-call"
from __future__ import annotations

import contextlib
import json
import signal
import sys
import threading
from pathlib import Path

import can
import canopen
import numpy as np
import pytest

from canbus.od import load_od
from skin.commands.common.busargs import DEFAULT_CHANNELS
from tests.support.rigs.children import spawn
from tests.support.rigs.waiting import holds_for, wait_until

REST_SCENE = """
[scene]
name = "rest"
description = "one untouched 3-axis patch"
mode = "xyz"
rate_hz = 100.0
seed = 0

[[patches]]
node_id = 1

[[loads]]
kind = "idle"
"""


NO_VALUE = -0x8000  # a force PDO's INTEGER16 "no value"


def _skin(*args: str) -> list[str]:
    return [sys.executable, "-m", "skin.cli", *args]


@pytest.mark.slow
def test_an_outside_master_drives_sync_and_tares(udp_port: int, tmp_path: Path) -> None:
    (tmp_path / "rest.toml").write_text(REST_SCENE)
    config = tmp_path / "host.toml"
    config.write_text(f"""
[host]
sync = "external"
tare_threshold_N = 0.2

[bus]
interface = "udp_multicast"
options = {{ port = {udp_port} }}

[[patches]]
node_id = 1
""")
    patches = spawn(_skin("sim", "run", str(tmp_path / "rest.toml"), "-i", "udp_multicast",
                          "--bus-kwargs", f"port={udp_port}"))
    host = None
    bus = can.Bus(interface="udp_multicast", channel=DEFAULT_CHANNELS["udp_multicast"],
                  port=udp_port)
    master = canopen.Network(bus)
    master.connect()
    try:
        patches.wait_for("Ctrl-C stops", timeout=60)
        host = spawn(_skin("run", str(config), "--json", str(tmp_path / "run.json")))
        remote = master.add_node(canopen.RemoteNode(65, load_od("skin-forces", 65)))
        remote.tpdo.read(from_od=True)
        samples: list[list[int]] = []
        lock = threading.Lock()

        def on_sample(pdo: object) -> None:
            with lock:
                samples.append([v.raw for n in range(1, 8) for v in remote.tpdo[n]][:27])

        remote.tpdo[7].add_callback(on_sample)

        def operational() -> bool:  # the force node starts with the host
            assert host is not None and host.running(), host and host.output()
            with contextlib.suppress(canopen.nmt.NmtError):
                remote.nmt.wait_for_heartbeat(1.5)
            return remote.nmt.state == "OPERATIONAL"

        wait_until(operational, what="the host's force node operational", timeout=60)
        holds_for(lambda: not samples, 1.0, what="the host waits for our SYNC")
        master.sync.start(0.01)
        wait_until(lambda: len(samples) >= 50, what="50 force samples on our SYNC")
        remote.sdo.download(0x2007, 0, b"\x01")  # tare at rest
        with lock:
            samples.clear()
        wait_until(lambda: len(samples) >= 40, what="40 force samples after the tare")
        with lock:
            after = np.array(samples[-20:], dtype=float)  # well after the tare took effect
        valued = after[after != NO_VALUE]  # a sample cut short on a busy machine has gaps
        assert valued.size >= after.size / 2
        assert np.abs(valued).max() <= 15  # mN: near zero after the tare
        master.sync.stop()
        assert host.stop(signal.SIGINT) == 0, host.output()
        record = json.loads((tmp_path / "run.json").read_text())
        assert record["stats"]["sync_cycles"] >= 90 and record["stats"]["frames_out"] > 0
        assert record["stats"]["sync_overruns"] == 0  # it produced no SYNC of its own
    finally:
        master.disconnect()
        for child in (host, patches):
            if child is not None and child.running():
                child.stop(signal.SIGINT)
