"""The exact start and stamp of frames sent on a real-time timed wire, however late the
sending thread ran: for tests that must hold on a loaded machine."""

from __future__ import annotations

import pytest

STAMP = 5e-7  # a float time.time() near 1.8e9 s resolves 0.24 us: timestamps are that exact


def check_starts(stamps: list[float], sent: list[tuple[float, float]], bits: int,
                 bitrate: int) -> None:
    """Frames of ``bits`` bits from one node on an otherwise quiet wire, ``sent`` the wire's
    clock (``bus.now()``) just before and after each send: each starts at its submission
    or, if the wire was taken, right after the previous frame's intermission; its stamp is
    its start plus its bits less the intermission. Exact, however late the sends or the
    reader ran."""
    ifs = 3 / bitrate
    for k, (stamp, (before, after)) in enumerate(zip(stamps, sent, strict=True)):
        start = stamp - bits / bitrate + ifs
        free = stamps[k - 1] + ifs if k else -1.0
        if after <= free:  # queued while the previous one was on the wire: back to back
            assert start == pytest.approx(free, abs=STAMP)
        else:
            assert max(before, free) - STAMP <= start <= after + STAMP
