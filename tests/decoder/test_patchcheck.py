"""The checks that see the whole patch: limits from held-out rows, the pattern and the departure
judged together, episodes told from exchangeable rows, and lm-mlp's promise on small scene
pairs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from decoder.patchcheck import (
    EXCHANGEABLE_RATIO,
    NO_LIMIT,
    SLACK,
    DepartureCheck,
    PatternCheck,
    block_margin,
    conformal_limit,
    exchangeability,
    held_out_distances,
    relative_departure,
)
from decoder.reasons import Reason
from decoder.registry import create_decoder

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels

finite = st.floats(-1e6, 1e6, allow_nan=False)


@settings(max_examples=200)
@given(st.lists(finite, min_size=1, max_size=300), st.floats(0.5, 0.999))
def test_the_limit_is_the_split_conformal_rank(values: list[float], q: float) -> None:
    limit = conformal_limit(np.array(values), q)
    ordered = sorted(values)
    rank = min(math.ceil((len(values) + 1) * q), len(values))
    assert limit == max(ordered[rank - 1], 1e-300)
    # at most a share 1 - q of the held-out values lie above it (fewer when the rank is past m)
    assert np.mean(np.array(values) > limit) <= 1 - q + 1e-12


def test_no_held_out_value_means_no_limit() -> None:
    assert conformal_limit(np.empty(0), 0.99) == NO_LIMIT


def test_a_fresh_sample_of_the_training_distribution_passes_at_the_stated_rate() -> None:
    """Exchangeable data: the share of new samples past a limit set on m held-out values is
    about 1 - q, far below it with the slack."""
    rng = np.random.default_rng(0)
    held = rng.chisquare(9, 400)
    fresh = rng.chisquare(9, 200_000)
    assert np.mean(fresh > conformal_limit(held, 0.99)) < 0.02
    assert np.mean(fresh > SLACK * conformal_limit(held, 0.99)) < 0.002


def _episodes(n: int, episodes: int, seed: int) -> np.ndarray:
    """Rows in order, a few long episodes each with its own pattern (a grasp's cycles)."""
    rng = np.random.default_rng(seed)
    shapes = rng.uniform(0.0, 1.0, (episodes, 9))
    which = np.repeat(np.arange(episodes), -(-n // episodes))[:n]
    envelope = rng.uniform(0.2, 1.0, n)
    return np.asarray(shapes[which] * envelope[:, None] + rng.normal(0, 0.01, (n, 9)))


def test_exchangeable_rows_and_episodes_are_told_apart() -> None:
    iid = np.random.default_rng(1).uniform(0.0, 5.0, (800, 9))
    _, ratio = exchangeability(iid)
    assert 0.5 < ratio < 1.5
    _, ratio = exchangeability(_episodes(800, 5, seed=2))
    assert ratio > 5 * EXCHANGEABLE_RATIO


def test_held_out_blocks_are_measured_against_the_other_rows() -> None:
    x = np.random.default_rng(3).normal(size=(200, 3))
    x[150:] += 10.0  # the last block is far from the rest
    blocks = [np.arange(0, 100), np.arange(100, 150), np.arange(150, 200)]
    d = held_out_distances(x, blocks)
    assert d[150:].min() > 10 * np.median(d[:150])


def test_block_margin_covers_what_a_new_block_needs() -> None:
    rng = np.random.default_rng(4)
    assert block_margin(rng.uniform(0, 1, (1000, 4))) < 0.02  # exchangeable: barely any
    x = _episodes(1000, 4, seed=5)
    margin = block_margin(x)
    assert margin > 0.05
    assert block_margin(np.ones((10, 3))) == 0.0


def test_the_pattern_check_sees_the_patch_as_a_whole() -> None:
    """Two taxels that always move together: each value on its own is familiar, their parting
    is not."""
    rng = np.random.default_rng(6)
    common = rng.uniform(0, 4, (600, 1))
    x = np.hstack([common + rng.normal(0, 0.02, (600, 2)), rng.uniform(0, 4, (600, 7))])
    blocks, _ = exchangeability(x)
    check = PatternCheck.fit(x, blocks)
    assert check.inside(x).mean() > 0.98
    apart = x[:50].copy()
    apart[:, 0] = 4.0 - apart[:, 1]
    assert not check.inside(apart[np.abs(apart[:, 0] - apart[:, 1]) > 0.5]).any()
    nan = x[:2].copy()
    nan[0, 3] = np.nan
    assert check.inside(nan).tolist() == [False, True]
    assert bool(check.inside(x[0])) is True  # one sample as a vector


def _departure(n: int, seed: int, scale: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    physics = rng.uniform(0.0, 4.0, (n, 9))
    return rng.normal(0.0, scale, (n, 9)), physics


def test_the_departure_check_flags_the_patch_and_the_loaded_taxel() -> None:
    fitted, _ = _departure(800, 7)
    held, held_physics = _departure(200, 8)
    check = DepartureCheck.fit(fitted, held, held_physics, floor_N=0.25)
    fresh, physics = _departure(2000, 9)
    # a departure of constant size is a large relative one on light presses: the relative
    # check, at its 95 % held-out quantile with the slack, refuses a few light taxels
    assert check.inside(fresh, physics).mean() > 0.95
    many = fresh[:100] * 3.0  # every taxel a little further off: the patch as a whole
    assert check.inside(many, physics[:100]).mean() < 0.1
    one = fresh[:100].copy()
    light = physics[:100].copy()
    light[:, 2] = 0.3
    one[:, 2] = 0.09  # 30 % of a 0.3 N press: within the absolute spread, not relative to it
    inside = check.inside(one, light)
    assert not inside[:, 2].any()
    unloaded = light.copy()
    unloaded[:, 2] = 0.05  # below the floor: the relative check does not judge it
    assert relative_departure(one, unloaded, 0.25)[:, 2].max() == 0.0


@settings(max_examples=100)
@given(st.lists(st.floats(-10, 10, allow_nan=False), min_size=27, max_size=27),
       st.lists(st.floats(-10, 10, allow_nan=False), min_size=27, max_size=27))
def test_relative_departure_is_the_taxels_largest_over_its_loaded_components(
        dep: list[float], phys: list[float]) -> None:
    d, p = np.array(dep), np.array(phys)
    rel = relative_departure(d, p, 0.25)
    for t in range(9):
        parts = [abs(d[3 * t + c]) / abs(p[3 * t + c]) for c in range(3)
                 if abs(p[3 * t + c]) >= 0.25]
        assert rel[t] == pytest.approx(max(parts, default=0.0))
    d[4] = np.nan
    assert relative_departure(d, p, 0.25)[1] == np.inf


def test_lm_mlp_trained_on_episodes_keeps_its_own_scene(synth: object) -> None:
    """A training set of five long episodes: the validation rows (random rows of those
    episodes) cannot say how far the network departs on a sixth, so the departure check is
    not made, and new episodes of the scene are not refused; the readings' box is widened to
    what a held-out episode needs."""
    from tests.decoder.conftest import read_forces

    force = np.zeros((1200, 9, 3))
    force[..., 2] = 4.0 * _episodes(1200, 6, seed=10).clip(0.0, 1.0)
    r, f = read_forces(force, seed=10)
    decoder = create_decoder("lm-mlp", max_epochs=60).fit(r[:1000], f[:1000])
    meta = decoder.meta()["domain"]
    assert meta["exchangeable_ratio"] > EXCHANGEABLE_RATIO
    assert meta["departure_check"].startswith("off")
    assert decoder.domain_.departure is None and decoder.domain_.pattern is not None
    home = decoder.decode(r[1000:])  # the sixth episode
    assert (home.reason == Reason.EXTRAPOLATED).mean() <= 0.05
