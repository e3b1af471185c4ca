"""How fast a decoder decodes: batched throughput and single-sample latency, timed on the
decoder as it is (``skin bench`` reports them; ``skin calibrate`` ranks candidates by them)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np

from decoder.mlp import F64
from decoder.protocol import Decoder


def best_time(fn: Callable[[], object], repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def decode_speed(decoder: Decoder, r: F64, batch: int, repeats: int) -> tuple[float, float]:
    """(patch-samples/s batched, median latency of one patch-sample in microseconds)."""
    tiled = np.ascontiguousarray(np.resize(r, (batch, *r.shape[1:])))
    decoder.decode(tiled[:64])
    rate = batch / best_time(lambda: decoder.decode(tiled), repeats)
    one = np.ascontiguousarray(r[:1])
    laps = []
    for _ in range(200 * repeats):
        start = time.perf_counter()
        decoder.decode(one)
        laps.append(time.perf_counter() - start)
    return rate, 1e6 * statistics.median(laps)
