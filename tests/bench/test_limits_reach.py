"""``python -m tests.support.limits_reach``: lm-mlp's limits scaled with hindsight. Its figures
back a claim of docs/decoders.md, so with the limits as fitted it must judge a pair exactly as
``skin bench cross`` does, and scaling must move the flags the way a limit does."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from decoder.registry import create_decoder
from skin.benchmarks.judge import judge
from skin.benchmarks.pairs import pair_data, random_pair
from tests.support.limits_reach import PairStats, as_fitted, judge_scaled, pair_stats, reach

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels

N_TRAIN, N_TEST = 400, 120


@cache
def _stats(index: int) -> PairStats:
    return pair_stats(index, N_TRAIN, N_TEST)


@pytest.mark.parametrize("index", [0, 1])  # exchangeable rows, and a grasp (departure off)
def test_the_limits_as_fitted_judge_a_pair_as_bench_cross_does(index: int) -> None:
    stats = _stats(index)
    pair = random_pair(index)
    data = pair_data(pair, N_TRAIN, N_TEST, 1)
    deconv = create_decoder("deconv").fit(*data.train)
    fitted = judge("lm-mlp", create_decoder("lm-mlp").fit(*data.train), deconv, data, pair.mode)
    assert stats.episodes == (index == 1)
    scaled = judge_scaled(stats, as_fitted(stats))
    for key in ("flagged_home", "flagged_away", "error_home_pct", "error_away_pct", "bar_pct",
                "home_met", "away_met"):
        expected = fitted[key]
        assert scaled[key] == (expected if expected is None or isinstance(expected, bool)
                               else pytest.approx(expected, rel=1e-12)), key


def test_tighter_limits_flag_more_and_none_flag_only_the_boxes() -> None:
    stats = _stats(0)
    shares = [judge_scaled(stats, (s, s, s))["flagged_home"] for s in (0.25, 1.0, 4.0)]
    assert shares[0] > shares[1] >= shares[2]
    lifted = judge_scaled(stats, (np.inf, np.inf, np.inf))
    assert lifted["flagged_home"] == pytest.approx(float(np.mean(stats.home.boxed)))
    summary = reach([stats])
    assert summary["pairs"] == 1
    assert summary["reachable"] >= summary["best_common"]["met"] >= summary["met_as_fitted"]
