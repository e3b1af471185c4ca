"""The promise of ``skin bench cross``, pair by pair: at home few flags, away never silently
worse.

For every trained decoder and scene pair (trained on A, tested at home on another seed of A
and away on B): the share of taxels it flags EXTRAPOLATED at home and away, its floored
AveRelErr on the taxels it does not flag, and the bar: at most ``FACTOR`` x the larger of
deconv's on that pair (trained on A, tested on B) and its own at home; and at most
``HOME_SHARE`` flagged at home. Pairs come from the shipped scenes' matrix
(:func:`skin.benchmarks.decoders.cross_matrix`) and from :mod:`skin.benchmarks.pairs`
(fixed ones, and drawn ones with ``--random``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from skin.benchmarks.judge import HOME_SHARE, TRAINED, bar_pct, judge_pair
from skin.benchmarks.pairs import PAIRS, ScenePair, random_pair


def promise_rows(cells: Sequence[Mapping[str, Any]],
                 names: Sequence[str] = TRAINED) -> list[dict[str, Any]]:
    """The promise on every unseen cell of a train-scene x test-scene matrix whose seen cell
    (same scene, another seed) is there too."""
    by = {(c["decoder"], c["mode"], c["train"], c["test"]): c for c in cells}
    rows = []
    for c in cells:
        if c["decoder"] not in names or c["train"] is None or c["seen"]:
            continue
        home = by.get((c["decoder"], c["mode"], c["train"], c["train"]))
        ref = by.get(("deconv", c["mode"], c["train"], c["test"]))
        if home is None or ref is None:
            continue
        rows.append(row(c["decoder"], c["mode"], c["train"], c["test"], home, c, ref))
    return rows


def row(decoder: str, mode: str, train: str, test: str, home: Mapping[str, Any],
        away: Mapping[str, Any], deconv: Mapping[str, Any]) -> dict[str, Any]:
    """One promise row from three cells: the decoder at home and away, deconv away."""
    err_home, err_away = home["ave_rel_err_floored_pct"], away["ave_rel_err_floored_pct"]
    bar = bar_pct(deconv["ave_rel_err_floored_pct"], err_home)
    return {"decoder": decoder, "mode": mode, "train": train, "test": test,
            "flagged_home": home["flagged_share"], "flagged_away": away["flagged_share"],
            "error_home_pct": err_home, "error_away_pct": err_away,
            "deconv_away_pct": deconv["ave_rel_err_floored_pct"], "bar_pct": bar,
            "compared": away.get("compared"),
            "home_met": home["flagged_share"] <= HOME_SHARE,
            "away_met": err_away is None or (bar is not None and err_away <= bar)}


def pair_rows(pairs: Sequence[ScenePair], *, n_train: int, n_test: int, seed: int = 1,
              names: Sequence[str] = TRAINED,
              params: Mapping[str, Mapping[str, Any]] | None = None) -> list[dict[str, Any]]:
    """The promise on each of ``pairs`` (:func:`skin.benchmarks.judge.judge_pair`), one row per
    decoder."""
    rows = []
    for pair in pairs:
        judged = judge_pair(pair, n_train=n_train, n_test=n_test, seed=seed, names=names,
                            params=params)
        for r in judged["decoders"]:
            rows.append({"decoder": r["decoder"], "mode": pair.mode, "train": judged["train"],
                         "test": judged["test"], "pair": pair.name,
                         **{k: r[k] for k in ("flagged_home", "flagged_away", "error_home_pct",
                                              "error_away_pct", "deconv_away_pct", "bar_pct",
                                              "compared", "home_met", "away_met", "train_s")}})
    return rows


def run_pairs(quick: bool, params: Mapping[str, Mapping[str, Any]] | None,
              random: int = 0, first_seed: int = 0) -> dict[str, Any]:
    """``PAIRS`` (and ``random`` drawn pairs from ``first_seed``), 1000 training and 300 test
    samples (``quick``: 500 and 200)."""
    n_train, n_test = (500, 200) if quick else (1000, 300)
    pairs = [*PAIRS, *(random_pair(first_seed + k) for k in range(random))]
    return {"train_samples": n_train, "test_samples": n_test, "seed": 1,
            "random_pairs": random, "first_random_seed": first_seed,
            "rows": pair_rows(pairs, n_train=n_train, n_test=n_test, params=params)}


def summary(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """How many rows meet each half of the promise, and the worst of each."""
    judged = [r for r in rows if r["error_away_pct"] is not None and r["bar_pct"]]
    ratios = [r["error_away_pct"] / r["bar_pct"] for r in judged]
    return {"rows": len(rows), "home_met": sum(bool(r["home_met"]) for r in rows),
            "away_met": sum(bool(r["away_met"]) for r in rows),
            "worst_flagged_home": max((r["flagged_home"] for r in rows), default=None),
            "worst_error_over_bar": max(ratios, default=None)}
