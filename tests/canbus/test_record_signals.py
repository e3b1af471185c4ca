"""`skin sniff --record` stopped by SIGTERM, and killed by SIGKILL, beside python-can's
`can.logger` on the same udp_multicast bus (own group and port, see conftest.py), while
frames flow: bench/rigs/stop.py."""

from __future__ import annotations

from pathlib import Path

import can
import pytest

from bench.rigs.stop import IDS, run

RATE = 2000  # frames/s: 2 s of it fills one 128 KiB .blf container of can.logger's


def _python_can(path: Path) -> list[int]:
    with can.LogReader(path) as reader:
        return [int.from_bytes(m.data, "little") for m in reader
                if m.arbitration_id in IDS and len(m.data) == 4]


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf", ".pcap"])
def test_sigterm_and_kill_keep_the_recording_like_can_logger(
        udp_channel: str, udp_port: int, tmp_path: Path, suffix: str) -> None:
    result = run(suffix, udp_channel, udp_port, tmp_path, rate=RATE)
    ours, reference = result.termed, result.logger  # a SIGTERM closes ours complete

    record = result.termed_json
    assert record["stopped_by"] == "SIGTERM"
    frames = record["recording"]["frames"]  # type: ignore[index]
    assert frames >= len(ours)
    assert f"recorded {frames:,} frames to " in result.termed_stdout
    assert ours[0] == reference[0] == 0
    common = min(ours[-1], reference[-1])
    assert common >= RATE  # a span worth comparing: can.logger kept at least a second
    in_ours = sum(k <= common for k in ours)
    in_theirs = sum(k <= common for k in reference)
    assert abs(in_ours - in_theirs) <= 0.01 * in_theirs, (in_ours, in_theirs)
    before_term = result.sent_before[0.5]
    assert ours[:before_term] == list(range(before_term))  # nothing lost, in order

    cut = result.killed  # read with partial=True: a kill inside a write may cut a frame
    before_kill = result.sent_before[1.0]  # a kill -9 loses at most the last second
    assert cut[:before_kill] == list(range(before_kill))
    assert cut == list(range(len(cut))) and len(cut) <= result.sent
    if suffix != ".pcap":  # python-can reads the killed file too (.pcap: ours, strict)
        assert _python_can(result.killed_path)[:before_kill] == list(range(before_kill))
