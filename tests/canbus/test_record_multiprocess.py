"""`skin sniff` as its own process on udp_multicast: a real SIGINT keeps the whole recording.

A multicast group alone does not isolate tests: python-can binds the port on every
address and Linux delivers to it the datagrams of every group joined on that port, so
this test also takes a port of its own (``--bus-kwargs port=N``).
"""

from __future__ import annotations

import json
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import can

from canbus.tools.replay import Recording

FRAMES = 300


def _lines(stream: object, into: queue.Queue[str]) -> None:
    for line in stream:  # type: ignore[attr-defined]
        into.put(line)


def test_sigint_keeps_every_frame(udp_channel: str, udp_port: int, tmp_path: Path) -> None:
    port = udp_port
    out = tmp_path / "udp.log"
    proc = subprocess.Popen(
        [sys.executable, "-m", "skin.cli", "sniff", "-i", "udp_multicast", "-c", udp_channel,
         "--bus-kwargs", f"port={port}", "--view", "lines", "--record", str(out),
         "--json", str(tmp_path / "s.json"), "--seconds", "60"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 30
        while not out.exists():
            assert proc.poll() is None, proc.communicate()[1]
            assert time.monotonic() < deadline, "skin sniff did not start"
            time.sleep(0.02)  # the bus (joined socket) exists before the recording file
        lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=_lines, args=(proc.stdout, lines), daemon=True).start()
        sent = [can.Message(arbitration_id=0x181 + k % 7, data=k.to_bytes(2, "little"),
                            is_extended_id=False) for k in range(FRAMES)]
        with can.Bus(interface="udp_multicast", channel=udp_channel, port=port) as bus:
            for msg in sent:
                bus.send(msg)
        for _ in range(FRAMES):  # every frame was shown, so every frame was received
            lines.get(timeout=30)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    with Recording(out) as recording:
        got = [(m.arbitration_id, bytes(m.data)) for m in recording]
    assert got == [(m.arbitration_id, bytes(m.data)) for m in sent]
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["recording"]["frames"] == summary["frames"] == FRAMES
    assert f"recorded {FRAMES} frames to {out}" in err
