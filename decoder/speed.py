"""How fast a decoder decodes: batched throughput and single-sample latency, timed on the
decoder as it is (``skin bench`` reports them; ``skin calibrate`` ranks candidates by them)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np

from decoder.mlp import F64
from decoder.protocol import Decoder
from decoder.reasons import Reason


def best_time(fn: Callable[[], object], repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def _median_latency_us(decoder: Decoder, one: F64, repeats: int) -> float:
    decoder.decode(one)
    laps = []
    for _ in range(200 * repeats):
        start = time.perf_counter()
        decoder.decode(one)
        laps.append(time.perf_counter() - start)
    return 1e6 * statistics.median(laps)


def decode_speed(decoder: Decoder, r: F64, batch: int, repeats: int) -> tuple[float, float]:
    """(patch-samples/s batched over the test set tiled, median latency of one patch-sample in
    microseconds: the first test sample every taxel of which decodes, the common case; a
    flagged one takes the full path, :func:`flagged_latency`)."""
    tiled = np.ascontiguousarray(np.resize(r, (batch, *r.shape[1:])))
    decoder.decode(tiled[:64])
    rate = batch / best_time(lambda: decoder.decode(tiled), repeats)
    accepted = np.flatnonzero(decoder.decode(r).valid.reshape(r.shape[0], -1).all(axis=1))
    first = int(accepted[0]) if accepted.size else 0
    return rate, _median_latency_us(decoder, np.ascontiguousarray(r[first:first + 1]), repeats)


def flagged_latency(decoder: Decoder, r: F64, repeats: int) -> float | None:
    """Median latency of one patch-sample the decoder flags (None if it flags none of ``r``)."""
    flagged = np.flatnonzero((decoder.decode(r).reason == Reason.EXTRAPOLATED)
                             .reshape(r.shape[0], -1).any(axis=1))
    if not flagged.size:
        return None
    return _median_latency_us(decoder, np.ascontiguousarray(r[flagged[:1]]), repeats)
