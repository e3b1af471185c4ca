"""What ``skin decode`` says of a recording, in the recording's own terms.

The listen-only host that decodes a recording logs as a live host does ("patch 1 lost",
"invalid taxel-samples in the last 10 s"), on a clock that is not the recording's; offline
those lines mislead. The decode keeps the host quiet and reports instead, per patch and in
seconds from the recording's first frame: its samples and how many were complete, the
stretches in which it answered no SYNC (every taxel MISSING: silent, absent or unheard),
and its invalid taxel-samples by reason.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from canbus.master.dataplane import ForceFrame


@dataclass
class Silence:
    """SYNCs in a row that a patch answered with nothing."""

    from_s: float
    to_s: float
    syncs: int


@dataclass
class PatchReport:
    patch: int
    samples: int = 0
    complete: int = 0
    silent: list[Silence] = field(default_factory=list)
    invalid_by_reason: dict[str, int] = field(default_factory=dict)


@contextlib.contextmanager
def quiet_host() -> Iterator[None]:
    """Keep the listen-only host's live-bus log lines (a patch lost, invalid taxels in the
    last N s) to errors while it decodes a recording; the report says it instead."""
    logger = logging.getLogger("canbus.master")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def first_frame_time(path: str) -> float:
    """The bus time of a recording's first frame (0 for an empty one)."""
    from canbus.tools.recording import Recording

    with Recording(path) as recording:
        for msg in recording:
            return float(msg.timestamp)
    return 0.0


def report(frames: Sequence[ForceFrame], start: float) -> dict[int, PatchReport]:
    """Each patch's report; times in s from ``start`` (the recording's first frame)."""
    import numpy as np

    from decoder.reasons import Reason, reason_name

    out: dict[int, PatchReport] = {}
    was_silent: dict[int, bool] = {}
    for frame in frames:
        one = out.setdefault(frame.patch, PatchReport(frame.patch))
        one.samples += 1
        one.complete += bool(frame.complete)
        t = frame.timestamp - start
        silent = not frame.valid.any() and bool(np.all(frame.reason == Reason.MISSING))
        if silent and was_silent.get(frame.patch):
            one.silent[-1].to_s, one.silent[-1].syncs = t, one.silent[-1].syncs + 1
        elif silent:
            one.silent.append(Silence(t, t, 1))
        was_silent[frame.patch] = silent
        for code in frame.reason[~frame.valid].tolist():
            name = reason_name(int(code))
            one.invalid_by_reason[name] = one.invalid_by_reason.get(name, 0) + 1
    return dict(sorted(out.items()))


def lines(reports: dict[int, PatchReport]) -> list[str]:
    out = []
    for one in reports.values():
        text = f"patch {one.patch}: {one.samples:,} samples, {one.complete:,} complete"
        for gap in one.silent:
            text += (f"; no answer {gap.from_s:.3f}-{gap.to_s:.3f} s ({gap.syncs:,} SYNC"
                     f"{'s' if gap.syncs != 1 else ''})")
        if one.invalid_by_reason:
            text += "; invalid taxel-samples: " + ", ".join(
                f"{name} {n:,}" for name, n in sorted(one.invalid_by_reason.items()))
        out.append(text)
    return out


def to_json(reports: dict[int, PatchReport]) -> dict[str, Any]:
    return {str(p): asdict(r) for p, r in reports.items()}
