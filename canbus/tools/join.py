"""Join a patch's recorded samples (one per SYNC) to reference samples, by SYNC counter or
by time, on one clock.

- **By SYNC counter** (``"sync"``, when the reference names the counter each sample
  answers and the recording's SYNCs carry one): a reference sample joins the recorded
  sample whose SYNC has its counter and whose time, on the recording's clock, is nearest
  and within the tolerance (default: a quarter of the counter's wrap, 60 SYNC periods:
  the clock only has to tell the wraps apart).
- **By time** (``"time"``): the recorded sample whose SYNC is nearest in time, within the
  tolerance (default 40 % of the SYNC period, so no reference sample can fall within it
  of two SYNCs).

Every sample joins at most once, the nearest first; nothing is interpolated or reused.

The clock offset (reference time + offset = recording time) is given, or estimated: the
reference's total normal force and the recording's total pillar-z resistance (which a
press lowers) are laid on a grid of SYNC periods and cross-correlated, the best lag is
the coarse offset, and the median time difference of the pairs it joins refines it. A
reference with a SYNC counter and no time is laid on the grid by its counters, unwrapped
in order (so a gap in it must be shorter than one wrap, 240 SYNCs).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skin.errors import ConfigError

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
COUNTER_WRAP = 240
"""CiA 301's SYNC counter runs 1..240 (0x1019); it wraps after 240 SYNCs."""
TIME_TOLERANCE_PERIODS = 0.4
SYNC_TOLERANCE_PERIODS = COUNTER_WRAP / 4
MIN_CORRELATION = 0.5
"""The least correlation of load and readings an estimated clock offset must reach."""
MAX_GRID = 20_000_000


@dataclass(frozen=True)
class Join:
    """Pairs of (recorded sample, reference sample) indexes, and how they were found."""

    by: str  # "sync" or "time"
    tolerance_s: float
    clock_offset_s: float  # reference time + this = recording time
    offset_estimated: bool
    correlation: float | None  # of the estimate (None when the offset was given)
    recorded: NDArray[np.intp]  # (pairs,) indexes of the recorded samples
    reference: NDArray[np.intp]  # (pairs,) indexes of the reference samples


@dataclass(frozen=True)
class Series:
    """One side of a join: times (NaN if unknown), SYNC counters (0 if none) and a signal
    that grows with the load, for the clock estimate (NaN where the sample has none)."""

    time_s: F64
    counter: I64
    load: F64


def default_tolerance_s(by: str, period_s: float) -> float:
    return period_s * (SYNC_TOLERANCE_PERIODS if by == "sync" else TIME_TOLERANCE_PERIODS)


def join(recorded: Series, reference: Series, *, by: str, period_s: float,
         tolerance_s: float | None = None, clock_offset_s: float | None = None) -> Join:
    """Join ``reference`` to ``recorded`` (module docstring). Raises ConfigError when the
    clock offset must be estimated and cannot be."""
    if by not in ("sync", "time"):
        raise ConfigError("--join", f"must be 'sync' or 'time', got {by!r}")
    if not (math.isfinite(period_s) and period_s > 0):
        raise ConfigError("period", f"the SYNC period must be > 0 s, got {period_s!r}")
    tol = default_tolerance_s(by, period_s) if tolerance_s is None else tolerance_s
    if not (math.isfinite(tol) and tol > 0):
        raise ConfigError("--tolerance-ms", f"must be > 0, got {1000 * tol:g}")
    ref_time = reference.time_s
    if np.all(np.isnan(ref_time)):  # a counter, no time: lay it on the grid in order
        ref_time = unwrap(reference.counter) * period_s
        if clock_offset_s is not None:
            raise ConfigError("--clock-offset-ms", "the reference has no time_s: there is no "
                              "clock to offset (the SYNC counters align it)")
    correlation = None
    estimated = clock_offset_s is None
    if clock_offset_s is None:
        clock_offset_s, correlation = estimate_offset(
            recorded, dataclasses.replace(reference, time_s=ref_time), period_s=period_s, by=by)
    rec, ref = _match(recorded, ref_time + clock_offset_s, reference.counter, tol, by)
    return Join(by, tol, float(clock_offset_s), estimated, correlation, rec, ref)


def unwrap(counter: I64) -> F64:
    """SYNC counters in order -> a running count (each step taken as the shortest forward
    one, 1..240 counters)."""
    c = np.asarray(counter, dtype=np.int64)
    if c.size == 0:
        return np.zeros(0)
    steps = np.mod(np.diff(c) - 1, COUNTER_WRAP) + 1
    return np.concatenate(([0.0], np.cumsum(steps, dtype=np.float64)))


def estimate_offset(recorded: Series, reference: Series, *, period_s: float,
                    by: str) -> tuple[float, float]:
    """(offset in s, correlation): the coarse lag of the load cross-correlation on a grid of
    ``period_s``, refined to the median time difference of the pairs it joins."""
    rec_ok = np.isfinite(recorded.load) & np.isfinite(recorded.time_s)
    ref_ok = np.isfinite(reference.load) & np.isfinite(reference.time_s)
    if rec_ok.sum() < 3 or ref_ok.sum() < 3:
        raise ConfigError("--clock-offset-ms", "too few samples to estimate the clock offset "
                          f"({int(rec_ok.sum())} recorded, {int(ref_ok.sum())} reference): "
                          "give it")
    t0, u0 = float(recorded.time_s[rec_ok][0]), float(reference.time_s[ref_ok][0])
    a = _grid(recorded.time_s[rec_ok] - t0, recorded.load[rec_ok], period_s)
    b = _grid(reference.time_s[ref_ok] - u0, reference.load[ref_ok], period_s)
    lag, r = _best_lag(a, b)
    if not r >= MIN_CORRELATION:
        raise ConfigError("--clock-offset-ms", "could not estimate the clock offset: the "
                          f"reference's load and the recording's readings correlate at best "
                          f"{r:.2f} (at least {MIN_CORRELATION} needed): give it")
    coarse = t0 - u0 + lag * period_s
    rec, ref = _match(recorded, reference.time_s + coarse, reference.counter, period_s / 2, by)
    if rec.size == 0:
        return coarse, r
    return float(coarse + np.median(recorded.time_s[rec] - reference.time_s[ref] - coarse)), r


def _grid(t: F64, values: F64, period_s: float) -> tuple[F64, F64]:
    """(values, mask) on cells of ``period_s`` from t = 0."""
    cells = np.rint(t / period_s).astype(np.int64)
    if cells.min() < 0 or cells.max() >= MAX_GRID:
        raise ConfigError("--clock-offset-ms", f"the samples span {cells.max() * period_s:.0f} s "
                          "of one clock, too long to estimate the offset: give it")
    size = int(cells.max()) + 1
    grid, mask = np.zeros(size), np.zeros(size)
    grid[cells] = values - values.mean()
    mask[cells] = 1.0
    return grid, mask


def _best_lag(a: tuple[F64, F64], b: tuple[F64, F64]) -> tuple[int, float]:
    """The lag L maximising the masked correlation of a[m + L] with b[m], and its value."""
    (x, mx), (y, my) = a, b
    size = 1 << math.ceil(math.log2(x.size + y.size))

    def xcorr(p: F64, q: F64) -> F64:  # out[L] = sum_m p[m + L] q[m], L = -(len q - 1)..len p - 1
        full = np.fft.irfft(np.fft.rfft(p, size) * np.conj(np.fft.rfft(q, size)), size)
        return np.concatenate((full[size - (q.size - 1):], full[: p.size]))

    n = np.rint(xcorr(mx, my))
    sx, sy = xcorr(x, my), xcorr(mx, y)
    sxx, syy, sxy = xcorr(x * x, my), xcorr(mx, y * y), xcorr(x, y)
    least = max(3.0, 0.5 * min(mx.sum(), my.sum()))
    with np.errstate(invalid="ignore", divide="ignore"):
        cov = sxy - sx * sy / n
        var = (sxx - sx * sx / n) * (syy - sy * sy / n)
        r = np.where((n >= least) & (var > 0), cov / np.sqrt(np.maximum(var, 1e-300)), -np.inf)
    best = int(np.argmax(r))
    return best - (y.size - 1), float(r[best])


def _match(recorded: Series, target: F64, counter: I64, tol: float, by: str
           ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Pairs (recorded, reference) within ``tol`` of ``target`` (recording times), each
    sample at most once, nearest first; ``by`` "sync" also needs equal counters."""
    order = np.argsort(recorded.time_s, kind="stable")
    ts = recorded.time_s[order]
    ok = np.isfinite(target)
    refs = np.flatnonzero(ok)
    lo = np.searchsorted(ts, target[refs] - tol, side="left")
    hi = np.searchsorted(ts, target[refs] + tol, side="right")
    pairs_rec, pairs_ref, gaps = [], [], []
    width = hi - lo
    for chunk in np.array_split(np.arange(refs.size), max(1, refs.size // 4096)):
        if chunk.size == 0:
            continue
        span = int(width[chunk].max(initial=0))
        if span == 0:
            continue
        idx = lo[chunk, None] + np.arange(span)
        inside = idx < hi[chunk, None]
        idx = np.minimum(idx, ts.size - 1)
        gap = np.abs(ts[idx] - target[refs[chunk], None])
        if by == "sync":
            inside &= recorded.counter[order][idx] == counter[refs[chunk], None]
        gap = np.where(inside, gap, np.inf)
        best = np.argmin(gap, axis=1)
        found = np.isfinite(gap[np.arange(chunk.size), best])
        pairs_rec.append(order[idx[np.arange(chunk.size), best][found]])
        pairs_ref.append(refs[chunk][found])
        gaps.append(gap[np.arange(chunk.size), best][found])
    if not pairs_rec:
        empty = np.zeros(0, dtype=np.intp)
        return empty, empty
    rec, ref, gap = (np.concatenate(x) for x in (pairs_rec, pairs_ref, gaps))
    nearest = np.argsort(gap, kind="stable")
    _, first = np.unique(rec[nearest], return_index=True)  # each recorded sample once
    keep = np.sort(nearest[first])
    return rec[keep].astype(np.intp), ref[keep].astype(np.intp)
