"""Per-patch bookkeeping of force samples: the latest, counts, rate, completeness, state.

Anything that looks like a force sample (:class:`SampleLike`: the bus reader's
``ForceSample``, the host's ``ForceFrame``) can be added, from any thread; a view asks
:meth:`SampleTracker.status` for a copy at a time of its choosing (bus time: the samples'
own timestamps, so a recording played back is judged on its recorded clock).

States: ``waiting`` (no sample yet), ``live`` (a sample within ``stale_s``), ``stale``
(none for longer), ``lost`` (none for ``lost_s``; or the last one had no valid taxel and
was incomplete, the host's withdrawal of a lost patch, and nothing followed within
``stale_s``).
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

WAITING, LIVE, STALE, LOST = "waiting", "live", "stale", "lost"
STATES = (WAITING, LIVE, STALE, LOST)
DEFAULT_WINDOW_S = 1.0
DEFAULT_STALE_S = 0.25
DEFAULT_LOST_S = 2.0


class SampleLike(Protocol):
    """One patch's forces at one time (``ForceSample``, ``ForceFrame``)."""

    @property
    def patch(self) -> int: ...
    @property
    def force_node(self) -> int: ...
    @property
    def timestamp(self) -> float: ...
    @property
    def force_N(self) -> NDArray[np.float64]: ...  # (9, 3) Fx, Fy, Fz; 0 where invalid
    @property
    def valid(self) -> NDArray[np.bool_]: ...  # (9,)
    @property
    def reason(self) -> NDArray[np.uint8]: ...  # (9,) decoder.reasons code, 0xFF unknown
    @property
    def complete(self) -> bool: ...


@dataclass(frozen=True)
class PatchStatus:
    """One patch as a view shows it, at one time."""

    patch: int
    force_node: int | None
    state: str
    samples: int
    incomplete: int  # samples not complete (the host said so, or PDOs went missing)
    partial: int  # of which the reader missed force PDOs (bus reader only)
    rate_hz: float  # samples per second over the last window (or since the first sample)
    complete_pct: float  # complete samples in the last window, % (0 without samples)
    age_s: float | None  # since the last sample
    last: SampleLike | None


@dataclass
class _Patch:
    force_node: int | None = None
    samples: int = 0
    incomplete: int = 0
    partial: int = 0
    first: float = 0.0
    last: SampleLike | None = None
    recent: deque[tuple[float, bool]] = field(default_factory=deque)


class SampleTracker:
    """The latest sample of every patch, and its figures over the last ``window_s``."""

    def __init__(self, *, window_s: float = DEFAULT_WINDOW_S,
                 stale_s: float = DEFAULT_STALE_S, lost_s: float = DEFAULT_LOST_S) -> None:
        self.window_s, self.stale_s, self.lost_s = window_s, stale_s, lost_s
        self._patches: dict[int, _Patch] = {}
        self._lock = threading.Lock()
        self.latest = -np.inf  # the newest sample timestamp

    def expect(self, patch: int, force_node: int | None = None) -> None:
        """Show ``patch`` (``waiting``) before its first sample."""
        with self._lock:
            record = self._patches.setdefault(patch, _Patch())
            if force_node is not None:
                record.force_node = force_node

    def add(self, sample: SampleLike, *, partial: bool = False) -> None:
        t = float(sample.timestamp)
        with self._lock:
            record = self._patches.get(sample.patch)
            if record is None:
                record = self._patches[sample.patch] = _Patch()
            if not record.samples:
                record.first = t
            record.force_node = sample.force_node
            record.samples += 1
            record.incomplete += not sample.complete
            record.partial += partial
            record.last = sample
            recent = record.recent
            recent.append((t, bool(sample.complete)))
            while recent and recent[0][0] <= t - self.window_s:
                recent.popleft()
            if t > self.latest:
                self.latest = t

    def patches(self) -> list[int]:
        with self._lock:
            return sorted(self._patches)

    def status(self, now: float | None = None) -> dict[int, PatchStatus]:
        """Every patch at bus time ``now`` (default: the newest sample's time)."""
        with self._lock:
            at = self.latest if now is None else now
            return {patch: self._status(patch, record, at)
                    for patch, record in sorted(self._patches.items())}

    def _status(self, patch: int, record: _Patch, now: float) -> PatchStatus:
        last = record.last
        if last is None:
            return PatchStatus(patch, record.force_node, WAITING, 0, 0, 0, 0.0, 0.0, None, None)
        age = max(0.0, now - float(last.timestamp))
        recent = [(t, ok) for t, ok in record.recent if now - self.window_s < t <= now]
        if now - record.first >= self.window_s:
            rate = len(recent) / self.window_s
        elif len(recent) >= 2:  # a younger patch: over the time since its first sample
            rate = (len(recent) - 1) / max(now - recent[0][0], 1e-9)
        else:
            rate = 0.0
        pct = 100.0 * sum(ok for _, ok in recent) / len(recent) if recent else 0.0
        withdrawn = not last.complete and not bool(np.any(last.valid))
        if age > self.lost_s or (withdrawn and age > self.stale_s):
            state = LOST
        elif age > self.stale_s:
            state = STALE
        else:
            state = LIVE
        return PatchStatus(patch, record.force_node, state, record.samples, record.incomplete,
                           record.partial, rate, pct, age, last)
