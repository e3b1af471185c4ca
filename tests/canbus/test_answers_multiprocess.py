"""The deployment's shape, with late answers on purpose: a patch (``tests.support.rigs.late_patch``,
which sends every 7th answer in two parts, the second after the next SYNC, and holds every
11th back until after the next SYNC) and the host (``skin run``) in two processes on
udp_multicast, python-can's own ``can.logger`` recording. The recording must show those
late answers, no complete force sample that is not the decode of one whole patch answer,
and one force sample per SYNC. Then ``skin replay --fast`` plays the recording into a
listen-only host: nothing is lost, there is one sample per recorded SYNC, and every sample
it found complete is the decode of one whole answer in the recording.
"""

from __future__ import annotations

import json
import os
import signal
import sys
from pathlib import Path

import can
import numpy as np
import pytest

from canbus.master.dataplane import ForceFrame
from canbus.master.forceframes import forces_to_mN
from canbus.master.host import HostManager
from canbus.master.hostconfig import load_host_config
from canbus.rxbuffer import DEFAULT_RCVBUF, enlarge_receive_buffer
from canbus.tools.recording import Recording
from tests.support.rigs.answer_audit import audit
from tests.support.rigs.children import run, spawn
from tests.support.rigs.waiting import wait_until

ANSWERS = 700  # the patch's answers before the host stops: 100 split, 54 held back

HEARD = ("frames_in", "unknown_frames", "bus_frames")  # every frame counted once, by kind

def _skin(*args: str) -> list[str]:
    return [sys.executable, "-m", "skin.cli", *args]


@pytest.mark.slow
def test_late_answers_never_make_a_mixed_sample(udp_channel: str, udp_port: int,
                                                tmp_path: Path) -> None:
    bus = ["-i", "udp_multicast", "-c", udp_channel, "--bus-kwargs", f"port={udp_port}"]
    config = tmp_path / "host.toml"
    config.write_text("[[patches]]\nnode_id = 1\n")
    recording = tmp_path / "run.log"
    logger = spawn([sys.executable, "-m", "can.logger", *bus, "-f", str(recording)],
                   env={**os.environ, "PYTHONUNBUFFERED": "1"})
    patch = spawn([sys.executable, "-m", "tests.support.rigs.late_patch", udp_channel,
                   str(udp_port)])
    host = None
    try:
        logger.wait_for("Connected to", timeout=60)
        patch.wait_for("Ctrl-C stops", timeout=60)
        host = spawn(_skin("run", str(config), *bus, "--json", str(tmp_path / "run.json")))
        patch.wait_for(f"answers {ANSWERS}", timeout=300)
        assert host.stop(signal.SIGINT) == 0, host.output()
        assert patch.stop(signal.SIGINT) == 0, patch.output()
    finally:
        logger.stop(signal.SIGINT)  # after the host: it has the last force frames
        for child in (host, patch):
            if child is not None and child.running():
                child.kill()
    late = patch.wait_for("split ", timeout=5).split()
    split, held = int(late[1]), int(late[3])
    result = audit(recording, [1])
    audited = result.patches[1]
    stats = json.loads((tmp_path / "run.json").read_text())["stats"]
    assert result.syncs == stats["sync_cycles"] >= ANSWERS
    # One force sample per SYNC, complete or not (the host's count, and the recording's).
    assert stats["samples"] == stats["sync_cycles"], stats
    assert audited.samples == result.syncs, (stats, result.verdict())
    # The late answers happened, and the host saw them as late. Most of the split ones show
    # split in the recording: a patch starved on a loaded machine may send an answer only
    # after the next SYNC has come, and a split answer then lies whole between two SYNCs.
    assert audited.split >= split // 2 and audited.doubled >= held - 1, result.verdict()
    assert (split, held) == (ANSWERS // 7, ANSWERS // 11 - ANSWERS // 77)  # by count
    assert stats["late_frames"] >= split + held, stats
    assert audited.complete >= 100, result.verdict()  # a check with something to check
    assert audited.mixed == [], result.verdict()  # every complete one is one whole answer

    with can.Bus(interface="udp_multicast", channel=udp_channel, port=udp_port) as bus_:
        enlarge_receive_buffer(bus_, DEFAULT_RCVBUF)
        decoded: list[ForceFrame] = []
        with HostManager(bus_, load_host_config(config), listen_only=True) as listener:
            listener.on_forces(decoded.append)
            replay = run(_skin("replay", str(recording), *bus, "--fast"), timeout=300)
            assert replay.returncode == 0, replay.stderr
            with Recording(recording) as frames:
                total = sum(1 for _ in frames)
            wait_until(lambda: sum(listener.stats()[k] for k in HEARD) >= total,
                       what=f"the listen-only host heard {total} frames")
        seen = listener.stats()
    assert sum(seen[k] for k in HEARD) == total  # replay --fast lost nothing
    # One sample per recorded SYNC, and every complete one the decode of one whole answer
    # of the recording. (Not necessarily the live host's choice: the live host closes a cycle
    # when it sends the next SYNC, the listen-only host when it hears it, so with an answer
    # late at that boundary each can take a different whole answer as the cycle's.)
    assert [frame.cycle for frame in decoded] == list(range(1, result.syncs + 1))
    complete = [frame for frame in decoded if frame.complete]
    assert len(complete) >= 100
    for frame in complete:
        mN, _ = forces_to_mN(frame.force_N, frame.valid)
        assert tuple(int(v) for v in np.ravel(mN)) in audited.answers, frame.cycle
