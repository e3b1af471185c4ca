"""`skin sniff --record` stopped by SIGTERM, and killed by SIGKILL, beside python-can's
`can.logger` on the same udp_multicast bus (own group and port, see conftest.py), while
frames flow: tests/support/rigs/stop.py."""

from __future__ import annotations

from pathlib import Path

import can
import pytest

from tests.support.rigs.stop import IDS, run

RATE = 2000  # frames/s: 2 s of it fills one 128 KiB .blf container of can.logger's


def _python_can(path: Path) -> list[int]:
    with can.LogReader(path) as reader:
        return [int.from_bytes(m.data, "little") for m in reader
                if m.arbitration_id in IDS and len(m.data) == 4]


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf", ".pcap"])
def test_sigterm_and_kill_keep_the_recording_like_can_logger(
        udp_channel: str, udp_port: int, tmp_path: Path, suffix: str) -> None:
    result = run(suffix, udp_channel, udp_port, tmp_path, rate=RATE)
    ours, reference = result.termed, result.logger

    # SIGTERM: every frame received is in the file, in order, nothing lost before it (the
    # sniffer's own count of what it received is the measure: no clock is involved)
    record = result.termed_json
    assert record["stopped_by"] == "SIGTERM"
    frames = record["recording"]["frames"]  # type: ignore[index]
    assert len(ours) == frames == record["frames"], (len(ours), frames, record["frames"])
    assert f"recorded {frames:,} frames to " in result.termed_stdout
    assert ours == list(range(len(ours)))
    assert len(ours) >= RATE  # it received a second of traffic, at least, before the stop
    # beside can.logger (which a SIGTERM cuts short), over the span both hold: no fewer
    common = min(ours[-1], reference[-1])
    assert sum(k <= common for k in ours) >= sum(k <= common for k in reference)

    # kill -9: a whole prefix of what was sent, read with partial=True (a kill inside a
    # write may cut a frame). That the prefix ends at most FLUSH_S before the kill is the
    # recorder's clock's promise: test_record_stream.py checks it on a clock it moves.
    cut = result.killed
    assert cut == list(range(len(cut))) and RATE <= len(cut) <= result.sent
    if suffix != ".pcap":  # python-can reads the killed file too (.pcap: ours, strict)
        theirs = _python_can(result.killed_path)
        assert theirs == list(range(len(theirs))) and abs(len(theirs) - len(cut)) <= 1
