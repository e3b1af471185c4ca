"""Joining recorded samples to reference samples: by SYNC counter or by time, the clock offset
given or estimated, gaps on both sides; every pair is a true pair and none is made up."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canbus.tools.join import Series, join, unwrap
from skin.errors import ConfigError

PERIOD = 0.01


def _world(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """SYNC times with jitter, their counters 1..240, and a load that varies."""
    rng = np.random.default_rng(seed)
    t = 1_700_000_000.0 + PERIOD * np.arange(n) + rng.normal(0, 2e-4, n)
    counter = (np.arange(n) + 17) % 240 + 1
    load = rng.uniform(0, 5, n) * (rng.uniform(size=n) > 0.2)
    return t, counter.astype(np.int64), load


def _sides(n: int, seed: int, rec_keep: np.ndarray, ref_keep: np.ndarray, offset: float
           ) -> tuple[Series, Series, np.ndarray, np.ndarray]:
    t, counter, load = _world(n, seed)
    rec_ids, ref_ids = np.flatnonzero(rec_keep), np.flatnonzero(ref_keep)
    readings = load + np.random.default_rng(seed + 1).normal(0, 0.05, n)  # the load it reads
    recorded = Series(t[rec_ids], counter[rec_ids], readings[rec_ids])
    ref_time = t[ref_ids] - offset + np.random.default_rng(seed + 2).normal(0, 1e-4, ref_ids.size)
    reference = Series(ref_time, counter[ref_ids], load[ref_ids])
    return recorded, reference, rec_ids, ref_ids


@pytest.mark.parametrize("by", ["sync", "time"])
def test_gaps_and_a_clock_offset_estimated(by: str) -> None:
    n = 3000
    rng = np.random.default_rng(4)
    rec_keep = rng.uniform(size=n) > 0.05  # lost samples
    ref_keep = rng.uniform(size=n) > 0.1  # a reference with gaps
    ref_keep[1000:1400] = False  # and a long one (more than a counter wrap)
    offset = 3723.4567  # the reference's clock is an hour behind
    recorded, reference, rec_ids, ref_ids = _sides(n, 4, rec_keep, ref_keep, offset)
    found = join(recorded, reference, by=by, period_s=PERIOD)
    assert found.offset_estimated and found.correlation is not None and found.correlation > 0.9
    assert found.clock_offset_s == pytest.approx(offset, abs=5e-4)
    np.testing.assert_array_equal(rec_ids[found.recorded], ref_ids[found.reference])
    assert found.recorded.size == np.count_nonzero(rec_keep & ref_keep)


def test_a_given_offset_and_tolerance_are_kept() -> None:
    n = 500
    keep = np.ones(n, dtype=bool)
    recorded, reference, rec_ids, ref_ids = _sides(n, 5, keep, keep, 0.0)
    late = Series(reference.time_s + 0.003, reference.counter, reference.load)
    tight = join(recorded, late, by="time", period_s=PERIOD, tolerance_s=0.001,
                 clock_offset_s=0.0)
    assert tight.recorded.size < n // 5 and not tight.offset_estimated
    right = join(recorded, late, by="time", period_s=PERIOD, tolerance_s=0.001,
                 clock_offset_s=-0.003)
    np.testing.assert_array_equal(rec_ids[right.recorded], ref_ids[right.reference])
    assert right.recorded.size == n


def test_the_counter_decides_between_near_syncs() -> None:
    n = 400
    keep = np.ones(n, dtype=bool)
    recorded, reference, rec_ids, ref_ids = _sides(n, 6, keep, keep, 0.0)
    # the reference's clock is off by 1.4 periods: by time the nearest SYNC is the wrong one
    skewed = Series(reference.time_s - 1.4 * PERIOD, reference.counter, reference.load)
    by_sync = join(recorded, skewed, by="sync", period_s=PERIOD, clock_offset_s=0.0)
    np.testing.assert_array_equal(rec_ids[by_sync.recorded], ref_ids[by_sync.reference])
    assert by_sync.recorded.size == n
    by_time = join(recorded, skewed, by="time", period_s=PERIOD, clock_offset_s=0.0)
    assert np.all(rec_ids[by_time.recorded] != ref_ids[by_time.reference])


def test_counters_alone_align_a_reference_without_time() -> None:
    n = 1500
    rng = np.random.default_rng(7)
    rec_keep = rng.uniform(size=n) > 0.05
    ref_keep = np.zeros(n, dtype=bool)
    ref_keep[300:900] = rng.uniform(size=600) > 0.02  # gaps shorter than a wrap
    recorded, reference, rec_ids, ref_ids = _sides(n, 7, rec_keep, ref_keep, 0.0)
    no_time = Series(np.full(ref_ids.size, np.nan), reference.counter, reference.load)
    found = join(recorded, no_time, by="sync", period_s=PERIOD)
    np.testing.assert_array_equal(rec_ids[found.recorded], ref_ids[found.reference])
    assert found.recorded.size == np.count_nonzero(rec_keep & ref_keep)
    with pytest.raises(ConfigError, match="no time_s"):
        join(recorded, no_time, by="sync", period_s=PERIOD, clock_offset_s=0.0)


def test_an_offset_that_cannot_be_estimated_says_so() -> None:
    n = 300
    keep = np.ones(n, dtype=bool)
    recorded, reference, _, _ = _sides(n, 8, keep, keep, 10.0)
    flat = Series(reference.time_s, reference.counter, np.random.default_rng(1).normal(size=n))
    with pytest.raises(ConfigError, match="--clock-offset-ms: could not estimate"):
        join(recorded, flat, by="time", period_s=PERIOD)


def test_unwrap_counts_through_the_wrap() -> None:
    np.testing.assert_array_equal(unwrap(np.array([239, 240, 1, 3, 3])), [0, 1, 2, 4, 244])


@given(st.integers(0, 2**32 - 1), st.floats(0.0, 0.5), st.floats(0.0, 0.5),
       st.sampled_from(["sync", "time"]))
@settings(max_examples=30, deadline=None)
def test_every_pair_is_true_and_none_made_up(seed: int, lost: float, gaps: float,
                                             by: str) -> None:
    n = 600
    rng = np.random.default_rng(seed)
    rec_keep, ref_keep = rng.uniform(size=n) >= lost, rng.uniform(size=n) >= gaps
    if rec_keep.sum() < 3 or ref_keep.sum() < 3:
        return
    recorded, reference, rec_ids, ref_ids = _sides(n, seed % 1000, rec_keep, ref_keep, 0.0)
    found = join(recorded, reference, by=by, period_s=PERIOD, clock_offset_s=0.0)
    np.testing.assert_array_equal(rec_ids[found.recorded], ref_ids[found.reference])
    assert np.unique(found.recorded).size == found.recorded.size
    assert np.unique(found.reference).size == found.reference.size
    assert found.recorded.size == np.count_nonzero(rec_keep & ref_keep)
