"""The deployment's shape on a busy machine: patches (`skin sim run`) and the host
(`skin run`) in two processes on udp_multicast, python-can's own `can.logger` recording,
and a fourth process keeping one core busy. Late answers happen here; the recording
must show no complete force sample that is not the decode of one whole patch answer,
and one force sample per SYNC. Then `skin replay --fast` plays the recording into a
listen-only host: nothing is lost, there is one sample per recorded SYNC, and where both
hosts found a cycle complete they publish the same forces.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import can
import numpy as np
import pytest

from bench.rigs.answer_audit import audit
from canbus.master.dataplane import ForceFrame
from canbus.master.forcenode import forces_to_mN
from canbus.master.host import HostManager
from canbus.master.hostconfig import load_host_config
from canbus.tools.recorder import DEFAULT_RCVBUF, enlarge_receive_buffer
from canbus.tools.replay import Recording

SECONDS = 10


def _skin(*args: str) -> list[str]:
    return [sys.executable, "-m", "skin.cli", *args]


def _stop(proc: subprocess.Popen[str], sig: int = signal.SIGINT) -> str:
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
    return err


@pytest.mark.slow
def test_late_answers_never_make_a_mixed_sample(udp_channel: str, udp_port: int,
                                                tmp_path: Path) -> None:
    bus = ["-i", "udp_multicast", "-c", udp_channel, "--bus-kwargs", f"port={udp_port}"]
    config = tmp_path / "host.toml"
    config.write_text("[[patches]]\nnode_id = 1\n")
    recording = tmp_path / "run.log"
    procs: list[subprocess.Popen[str]] = []

    def start(cmd: list[str]) -> subprocess.Popen[str]:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        procs.append(proc)
        return proc

    try:
        logger = start([sys.executable, "-m", "can.logger", *bus, "-f", str(recording)])
        hog = start([sys.executable, "-c", "while True: pass"])
        patches = start(_skin("sim", "run", "indenter", *bus))
        time.sleep(2.0)  # the logger and the patches are on the bus
        host = subprocess.run(_skin("run", str(config), *bus, "--seconds", str(SECONDS),
                                    "--json", str(tmp_path / "run.json")),
                              capture_output=True, text=True, timeout=SECONDS + 60)
        assert host.returncode == 0, host.stderr
        time.sleep(0.5)  # the last force frames reach the logger
        _stop(patches)
        _stop(hog, signal.SIGKILL)
        _stop(logger)
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    result = audit(recording, [1])
    patch = result.patches[1]
    stats = json.loads((tmp_path / "run.json").read_text())["stats"]
    assert result.syncs == stats["sync_cycles"] > 0.8 * SECONDS * 100
    # One force sample per SYNC, complete or not (the host's count, and the recording's).
    assert stats["samples"] == stats["sync_cycles"], stats
    assert patch.samples == result.syncs, (stats, result.verdict())
    assert patch.complete > 0.5 * result.syncs, result.verdict()
    assert patch.mixed == [], result.verdict()  # every complete one is one whole answer

    with can.Bus(interface="udp_multicast", channel=udp_channel, port=udp_port) as bus_:
        enlarge_receive_buffer(bus_, DEFAULT_RCVBUF)
        decoded: list[ForceFrame] = []
        with HostManager(bus_, load_host_config(config), listen_only=True) as listener:
            listener.on_forces(decoded.append)
            replay = subprocess.run(_skin("replay", str(recording), *bus, "--fast"),
                                    capture_output=True, text=True, timeout=120)
            assert replay.returncode == 0, replay.stderr
            time.sleep(1.0)
        seen = listener.stats()
    with Recording(recording) as frames:
        total = sum(1 for _ in frames)
    assert seen["frames_in"] + seen["unknown_frames"] + seen["bus_frames"] == total  # all
    # One sample per recorded SYNC; where both hosts found a cycle complete, the same forces.
    # (Which frames each judges late at a window's end depends on its own receive times.)
    assert [frame.cycle for frame in decoded] == list(range(1, result.syncs + 1))
    same = 0
    for frame, (complete, forces) in zip(decoded, patch.published, strict=False):
        if complete and frame.complete:
            mN, _ = forces_to_mN(frame.force_N, frame.valid)
            assert tuple(np.ravel(mN).tolist()) == forces, frame.cycle
            same += 1
    assert same > 0.5 * result.syncs
