"""`skin sniff` as its own process on udp_multicast: a real SIGINT keeps the whole recording.

A multicast group alone does not isolate tests: python-can binds the port on every
address and Linux delivers to it the datagrams of every group joined on that port, so
this test also takes a port of its own (``--bus-kwargs port=N``).
"""

from __future__ import annotations

import json
import signal
import sys
from pathlib import Path

import can

from canbus.tools.recording import Recording
from tests.support.rigs.children import spawn
from tests.support.rigs.waiting import wait_until

FRAMES = 300


def test_sigint_keeps_every_frame(udp_channel: str, udp_port: int, tmp_path: Path) -> None:
    port = udp_port
    out = tmp_path / "udp.log"
    proc = spawn([sys.executable, "-m", "skin.cli", "sniff", "-i", "udp_multicast", "-c",
                  udp_channel, "--bus-kwargs", f"port={port}", "--view", "lines", "--record",
                  str(out), "--json", str(tmp_path / "s.json"), "--seconds", "600"])
    proc.wait_for("Ctrl-C stops", stream="stderr", timeout=60)  # it receives
    sent = [can.Message(arbitration_id=0x181 + k % 7, data=k.to_bytes(2, "little"),
                        is_extended_id=False) for k in range(FRAMES)]
    with can.Bus(interface="udp_multicast", channel=udp_channel, port=port) as bus:
        for msg in sent:
            bus.send(msg)
    # every frame was shown, so every frame was received
    wait_until(lambda: len(proc.stdout().splitlines()) >= FRAMES, what=f"{FRAMES} lines")
    assert proc.stop(signal.SIGINT) == 0, proc.output()
    err = proc.stderr()
    with Recording(out) as recording:
        got = [(m.arbitration_id, bytes(m.data)) for m in recording]
    assert got == [(m.arbitration_id, bytes(m.data)) for m in sent]
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["recording"]["frames"] == summary["frames"] == FRAMES
    assert f"recorded {FRAMES} frames to {out}" in err
