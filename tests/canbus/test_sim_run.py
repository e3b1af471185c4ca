from __future__ import annotations

import json
import queue
import threading
import time
from pathlib import Path

import can
import canopen
import pytest

from canbus.od import load_od
from skin.cli import main

SECONDS = 0.6


def test_sim_run_serves_the_scene_until_the_time_is_up(request: pytest.FixtureRequest,
                                                       tmp_path: Path) -> None:
    channel = f"sim-run-{request.node.name}"
    master = canopen.Network()
    master.NOTIFIER_CYCLE = 0.05
    master.connect(interface="virtual", channel=channel)
    raw = can.Bus(interface="virtual", channel=channel)
    frames: queue.Queue[can.Message] = queue.Queue()
    notifier = can.Notifier(raw, [frames.put], timeout=0.05)
    out = tmp_path / "run.json"
    exit_code: list[int] = []
    argv = ["sim", "run", "indenter", "--seconds", str(SECONDS), "-i", "virtual", "-c", channel,
            "--json", str(out)]
    runner = threading.Thread(target=lambda: exit_code.append(main(argv)))
    try:
        started = time.monotonic()
        runner.start()
        seen: list[can.Message] = [frames.get(timeout=10.0)]
        assert (seen[0].arbitration_id, bytes(seen[0].data)) == (0x701, b"\x00")  # boot-up
        node = master.add_node(canopen.RemoteNode(1, load_od("skin-patch", 1)))
        node.sdo.RESPONSE_TIMEOUT = 1.0
        node.sdo[0x1017].raw = 50
        node.nmt.send_command(0x01)
        time.sleep(0.05)
        master.sync.transmit()
        runner.join(timeout=SECONDS + 5.0)
        wall = time.monotonic() - started
        assert not runner.is_alive(), "skin sim run did not stop"
    finally:
        runner.join()
        notifier.stop(timeout=1.0)
        raw.shutdown()
        master.disconnect()
    while not frames.empty():
        seen.append(frames.get_nowait())
    assert exit_code == [0]
    beats = [bytes(m.data) for m in seen[1:] if m.arbitration_id == 0x701]
    assert len(beats) >= 4 and set(beats) <= {b"\x7f", b"\x05"} and beats[-1] == b"\x05"
    tpdos = sorted(m.arbitration_id for m in seen if 0x180 <= m.arbitration_id < 0x580)
    assert tpdos == [0x181, 0x201, 0x281, 0x301, 0x381, 0x401, 0x481]  # 27 values, 7 TPDOs
    record = json.loads(out.read_text())
    assert record["syncs"] == 1 and record["frames"] == 7
    assert SECONDS <= record["seconds"] < wall
