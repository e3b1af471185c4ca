"""The promise of trained decoders on scene pairs (`skin bench cross`'s bar): at home (another
seed of the training scene) at most 5 % of taxels flagged; away, the floored error on the
taxels not flagged at most 2x the larger of deconv's on that pair and the decoder's own at
home; hybrid within 1.2x deconv."""

from __future__ import annotations

from typing import Any

import pytest

from skin.benchmarks.cross import promise_rows, summary
from skin.benchmarks.judge import FACTOR, HOME_SHARE, judge_pair
from skin.benchmarks.pairs import PAIRS, ScenePair, pair_data, random_pair

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels

BY_NAME = {p.name: p for p in PAIRS}
SHEAR_UNSEEN = ("3-axis, trained on pure presses, tested on sheared ones: the checks flag "
                "most of the away set, and on the 13-25 floored components left (of 200 "
                "samples) the network's Fz is about 25 % off, a departure that read noise "
                "also gives light presses at home (docs/decoders.md)")
KNOWN = {"sphere (0.1 % noise) -> slide": SHEAR_UNSEEN, "sphere -> oblique sphere": SHEAR_UNSEEN}


def _assert_promise(result: dict[str, Any]) -> None:
    for r in result["decoders"]:
        where = f"{r['decoder']} on {result['pair']}"
        assert r["flagged_home"] <= HOME_SHARE, where
        if r["error_away_pct"] is not None:
            assert r["error_away_pct"] <= FACTOR * max(r["deconv_away_pct"] or 0.0,
                                                      r["error_home_pct"] or 0.0), where
        if r["decoder"] == "hybrid" and r["error_away_pct"] and r["deconv_away_pct"]:
            assert r["error_away_pct"] <= 1.2 * r["deconv_away_pct"], where


@pytest.mark.parametrize("name", ["two spheres -> independent", "tilted plate -> independent"])
def test_the_promise_holds_on_z_only_pairs(name: str) -> None:
    """Two indenters at once and a tilted plate (three degrees of freedom), tested on the
    paper's independent loads: the issue's two z-only counterexamples."""
    _assert_promise(judge_pair(BY_NAME[name], n_train=500, n_test=200))


@pytest.mark.slow
@pytest.mark.parametrize("pair", [
    pytest.param(p, id=p.name, marks=[pytest.mark.xfail(reason=KNOWN[p.name])]
                 if p.name in KNOWN else []) for p in PAIRS])
def test_the_promise_on_every_pair_of_bench_cross(pair: ScenePair) -> None:
    _assert_promise(judge_pair(pair, n_train=500, n_test=200))


def test_pairs_are_reproducible_and_read_as_their_mode() -> None:
    pair = random_pair(7)
    a, b = pair_data(pair, 40, 20, seed=3), pair_data(pair, 40, 20, seed=3)
    for x, y in ((a.train, b.train), (a.home, b.home), (a.away, b.away)):
        assert (x[0] == y[0]).all() and (x[1] == y[1]).all()
    assert a.train[0].shape == (40, 9, pair.pillars) and a.away[1].shape == (20, 9, 3)
    if pair.mode == "z":
        assert not a.away[1][..., :2].any()
    other = pair_data(pair, 40, 20, seed=4)
    assert not (other.home[1] == a.home[1]).all()
    assert {random_pair(s).mode for s in range(20)} == {"z", "xyz"}


def test_promise_rows_judge_each_unseen_cell_against_its_home_and_deconv() -> None:
    def cell(decoder: str, train: str, test: str, err: float | None,
             flagged: float) -> dict[str, Any]:
        return {"decoder": decoder, "mode": "z", "train": train, "test": test,
                "seen": train == test, "ave_rel_err_floored_pct": err,
                "flagged_share": flagged, "compared": 50}

    cells = [cell("deconv", "a", "a", 1.0, 0.0), cell("deconv", "a", "b", 2.0, 0.1),
             cell("lm-mlp", "a", "a", 1.5, 0.02), cell("lm-mlp", "a", "b", 3.9, 0.5),
             cell("hybrid", "a", "a", 1.0, 0.06), cell("hybrid", "a", "b", 4.1, 0.0),
             cell("lm-mlp", "b", "a", 9.0, 0.0)]  # no home cell for b: not judged
    rows = {r["decoder"]: r for r in promise_rows(cells)}
    assert set(rows) == {"deconv", "lm-mlp", "hybrid"}
    assert rows["lm-mlp"]["bar_pct"] == pytest.approx(4.0) and rows["lm-mlp"]["away_met"]
    assert rows["hybrid"]["bar_pct"] == pytest.approx(4.0) and not rows["hybrid"]["away_met"]
    assert not rows["hybrid"]["home_met"] and rows["lm-mlp"]["home_met"]
    s = summary(list(rows.values()))
    assert s["home_met"] == 2 and s["away_met"] == 2 and s["worst_error_over_bar"] == 4.1 / 4
