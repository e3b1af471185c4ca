"""`skin sniff --record` stopped by SIGTERM, and killed by SIGKILL, beside python-can's
`can.logger` on the same udp_multicast bus (own group and port, see conftest.py).

One sender (this process) numbers every frame. Three recorders run as processes of their
own: `can.logger -f`, `skin sniff --record` ended by SIGTERM, `skin sniff --record` ended
by SIGKILL, the two signals sent at the same moment while frames are flowing. can.logger
has no SIGTERM handler, so it dies with its buffered tail unwritten (and, for .blf, with
the header it wrote at the start); its recording is read with ``partial=True``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest

from canbus.tools.replay import Recording

RATE = 2000  # frames/s: 2 s of it fills one 128 KiB .blf container of can.logger's
SEND_S, SIGNAL_AT_S = 2.0, 1.6
IDS = frozenset((0x181, 0x182, 0x183))


def _numbers(path: Path, *, partial: bool) -> list[int]:
    with Recording(path, partial=partial) as recording:
        return [int.from_bytes(m.data, "little") for m in recording
                if m.arbitration_id in IDS and len(m.data) == 4]


def _python_can(path: Path) -> list[int]:
    with can.LogReader(path) as reader:
        return [int.from_bytes(m.data, "little") for m in reader
                if m.arbitration_id in IDS and len(m.data) == 4]


def _wait_ready(procs: list[subprocess.Popen[str]], files: list[Path], logger_out: Path) -> None:
    deadline = time.monotonic() + 30
    while not (all(f.exists() for f in files) and "Connected to" in logger_out.read_text()):
        for proc in procs:
            assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the recorders did not start"
        time.sleep(0.02)
    time.sleep(0.3)  # the sniffers' Notifier starts just after their recording file


def _send(bus: can.BusABC, stop: list[subprocess.Popen[str]],
          kill: subprocess.Popen[str]) -> tuple[int, float, list[float]]:
    """Send numbered frames at RATE for SEND_S; at SIGNAL_AT_S SIGTERM ``stop`` and SIGKILL
    ``kill``. (frames sent, when the signals went, when each frame went)."""
    sent_at: list[float] = []
    signalled = 0.0
    started = time.monotonic()
    while (now := time.monotonic()) - started < SEND_S:
        if not signalled and now - started >= SIGNAL_AT_S:
            signalled = time.monotonic()
            for proc in stop:
                proc.send_signal(signal.SIGTERM)
            kill.send_signal(signal.SIGKILL)
        due = int((now - started) * RATE)
        while len(sent_at) < due:
            k = len(sent_at)
            bus.send(can.Message(arbitration_id=0x181 + k % 3, data=k.to_bytes(4, "little"),
                                 is_extended_id=False))
            sent_at.append(time.monotonic())
        time.sleep(0.001)
    return len(sent_at), signalled, sent_at


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf", ".pcap"])
def test_sigterm_and_kill_keep_the_recording_like_can_logger(
        udp_channel: str, udp_port: int, tmp_path: Path, suffix: str) -> None:
    bus_args = ["-i", "udp_multicast", "-c", udp_channel, "--bus-kwargs", f"port={udp_port}"]
    theirs, termed, killed = (tmp_path / f"{name}{suffix}" for name in
                              ("logger", "termed", "killed"))
    summary = tmp_path / "termed.json"
    logger_out = tmp_path / "logger.out"
    logger_out.write_text("")
    env = os.environ | {"PYTHONUNBUFFERED": "1"}
    sniff = [sys.executable, "-m", "skin.cli", "sniff", *bus_args, "--view", "none"]
    with logger_out.open("w") as out:
        procs = [
            subprocess.Popen([sys.executable, "-m", "can.logger", *bus_args, "-f", str(theirs)],
                             stdout=out, stderr=subprocess.STDOUT, text=True, env=env),
            subprocess.Popen([*sniff, "--record", str(termed), "--json", str(summary)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True),
            subprocess.Popen([*sniff, "--record", str(killed)], stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL, text=True)]
        try:
            _wait_ready(procs, [termed, killed], logger_out)
            with can.Bus(interface="udp_multicast", channel=udp_channel, port=udp_port) as bus:
                sent, signalled, sent_at = _send(bus, procs[:2], procs[2])
            stdout, stderr = procs[1].communicate(timeout=30)
            procs[0].wait(timeout=30)
            procs[2].wait(timeout=30)
        finally:
            for proc in procs:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
    assert procs[1].returncode == 0, stderr
    assert procs[2].returncode == -signal.SIGKILL

    ours = _numbers(termed, partial=False)  # a SIGTERM closes it complete
    record = json.loads(summary.read_text())
    assert record["stopped_by"] == "SIGTERM"
    assert record["recording"]["frames"] >= len(ours)
    assert f"recorded {record['recording']['frames']:,} frames to {termed}" in stdout
    reference = _numbers(theirs, partial=True)
    assert ours[0] == reference[0] == 0
    common = min(ours[-1], reference[-1])
    assert common >= RATE  # a span worth comparing: can.logger kept at least a second
    in_ours = sum(k <= common for k in ours)
    in_theirs = sum(k <= common for k in reference)
    assert abs(in_ours - in_theirs) <= 0.01 * in_theirs, (in_ours, in_theirs)
    before_term = sum(t <= signalled - 0.5 for t in sent_at)
    assert ours[:before_term] == list(range(before_term))  # nothing lost, in order

    cut = _numbers(killed, partial=True)  # a kill inside a write may cut the last frame
    before_kill = sum(t <= signalled - 1.0 for t in sent_at)  # at most 1 s lost
    assert cut[:before_kill] == list(range(before_kill))
    assert cut == list(range(len(cut))) and len(cut) <= sent
    if suffix != ".pcap":  # python-can reads the killed file too (.pcap: ours, strict)
        assert _python_can(killed)[:before_kill] == list(range(before_kill))
