"""Speed against error: the measurements behind ``skin bench`` and ``skin bench cross``.

Pure functions of arrays (the command builds the datasets with the simulator):
fit time, batched decode throughput, single-sample latency, accuracy against
the oracle, the paper's Table 1 sweep, LM against SciPy per iteration, and the
train-scene x test-scene matrix with the share of taxels each decoder flags.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import scipy.optimize

from decoder.lm import LMOptions, train_lm
from decoder.lmmlp import LMMLPDecoder
from decoder.metrics import ErrorReport, evaluate
from decoder.mlp import F64, Layout, forward, jacobian, mapminmax, minmax_range, nguyen_widrow
from decoder.oracle import oracle_decode
from decoder.protocol import Decoded
from decoder.reasons import Reason
from decoder.registry import create_decoder
from decoder.speed import best_time, decode_speed, flagged_latency

Split = tuple[F64, F64, F64, F64]  # train r, train F, test r, test F
Params = dict[str, dict[str, Any]]
"""Keyword parameters per decoder name (e.g. the goal's units for lm-mlp and hybrid)."""

PAPER_TABLE1 = {5: 3.07, 6: 2.95, 7: 2.63, 8: 2.19, 9: 1.96, 10: 1.72, 11: 1.83, 12: 1.98,
                13: 2.17, 14: 2.06}
"""AveRelErr (%) of the paper's Table 1 by hidden nodes."""


def bench_decoders(
    splits: Sequence[Split], crosstalk: F64, mode: str, names: Sequence[str], *,
    batch: int, repeats: int, params: Params | None = None, speed: bool = True,
) -> dict[str, Any]:
    """Accuracy (mean over splits) and, if ``speed``, speed of every decoder; the oracle."""
    oracle = [oracle_decode(s[2], crosstalk) for s in splits]
    reports = [evaluate(s[3], o.force_N, o.valid, mode=mode) for s, o in zip(splits, oracle,
                                                                             strict=True)]
    out: dict[str, Any] = {"oracle": {
        key: float(np.mean([getattr(r, key) for r in reports]))
        for key in ("ave_rel_err_pct", "ave_rel_err_floored_pct", "rmse_pct_fs")}}
    out["oracle"]["covered_pct"] = covered_pct(reports)
    rows = []
    for name in names:
        fits, errs, decoder = [], [], None
        for r_train, f_train, r_test, f_test in splits:
            decoder = create_decoder(name, **(params or {}).get(name, {}))
            start = time.perf_counter()
            decoder.fit(r_train, f_train)
            fits.append(time.perf_counter() - start)
            decoded = decoder.decode(r_test)
            errs.append(evaluate(f_test, decoded.force_N, decoded.valid, mode=mode))
        assert decoder is not None
        row: dict[str, Any] = {"name": name}
        for key in ("ave_rel_err_pct", "ave_rel_err_floored_pct", "rmse_pct_fs",
                    "max_rel_err_floored_pct"):
            row[key] = float(np.mean([getattr(e, key) for e in errs]))
        row["per_seed_ave_rel_err_pct"] = [e.ave_rel_err_pct for e in errs]
        row["masked"] = int(sum(e.masked for e in errs))
        row["covered_pct"] = covered_pct(errs)
        row["train_s"] = float(np.mean(fits))
        if speed:
            rate, latency = decode_speed(decoder, splits[0][2], batch, repeats)
            row.update(decode_samples_per_s=rate, latency_us=latency,
                       latency_flagged_us=flagged_latency(decoder, splits[0][2], repeats))
        rows.append(row)
    out["decoders"] = rows
    out["best"] = min(rows, key=lambda r: r["ave_rel_err_pct"])["name"] if rows else None
    return out


def covered_pct(reports: Sequence[ErrorReport]) -> float:
    """The share of the taxels the reports' figures cover together, in %."""
    taxels = sum(r.taxels for r in reports)
    return 100.0 * sum(r.covered for r in reports) / taxels if taxels else 0.0


def table1(splits: Sequence[Split], mode: str, scene: str,
           hidden: Sequence[int] = tuple(range(5, 15)),
           params: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """The paper's Table 1: lm-mlp AveRelErr by hidden nodes over splits (mean, median and
    spread), beside the paper's figure for the same size. As the paper scores it: the
    network's answer on every test component (``predict``), flagged or not; the share its
    domain checks flag is given beside."""
    rows = []
    for h in hidden:
        errs, epochs, flagged = [], [], []
        for r_train, f_train, r_test, f_test in splits:
            decoder = LMMLPDecoder(**{**(params or {}), "hidden": h}).fit(r_train, f_train)
            result = decoder.train_result
            epochs.append(0 if result is None else result.nit)
            errs.append(evaluate(f_test, decoder.predict(r_test), mode=mode))
            flagged.append(float(np.mean(decoder.decode(r_test).reason == Reason.EXTRAPOLATED)))
        rows.append(_table1_row(scene, h, errs, epochs, flagged))
    return rows


def _table1_row(scene: str, hidden: int, errs: Sequence[Any], epochs: list[int],
                flagged: list[float]) -> dict[str, Any]:
    per_seed = [float(e.ave_rel_err_pct) for e in errs]
    mean, median = float(np.mean(per_seed)), float(np.median(per_seed))
    q1, q3 = (float(v) for v in np.quantile(per_seed, [0.25, 0.75]))
    paper = PAPER_TABLE1.get(hidden)
    return {"scene": scene, "hidden": hidden, "ave_rel_err_pct": mean,
            "median_ave_rel_err_pct": median, "min_ave_rel_err_pct": min(per_seed),
            "max_ave_rel_err_pct": max(per_seed), "q1_ave_rel_err_pct": q1,
            "q3_ave_rel_err_pct": q3,
            "ave_rel_err_floored_pct": float(np.mean([e.ave_rel_err_floored_pct for e in errs])),
            "median_ave_rel_err_floored_pct":
                float(np.median([e.ave_rel_err_floored_pct for e in errs])),
            "per_seed_ave_rel_err_pct": per_seed, "epochs": epochs,
            "flagged_share": float(np.mean(flagged)), "paper_ave_rel_err_pct": paper,
            "at_most_paper": None if paper is None else mean <= paper,
            "median_at_most_paper": None if paper is None else median <= paper,
            "seeds_at_most_paper": None if paper is None else sum(v <= paper for v in per_seed)}


def analytic_throughput(pillars: int, batch: int, repeats: int) -> float:
    """Taxel-samples/s of the analytic decoder on random in-range input."""
    rng = np.random.default_rng(0)
    decoder = create_decoder("analytic")
    r0 = np.array([1000.0, 1414.2, 1414.2])[:pillars]
    r = r0 * (1.0 + rng.uniform(-0.1, 0.0, (batch, 9, pillars)))
    decoder.decode(r[:64])
    return 9 * batch / best_time(lambda: decoder.decode(r), repeats)


def lm_vs_scipy(x: F64, y: F64, hidden: int, scipy_iterations: int) -> dict[str, Any]:
    """Our LM and SciPy's MINPACK LM on the same scaled problem from the same start."""
    xs = mapminmax(x, *minmax_range(x))
    ys = mapminmax(y, *minmax_range(y))
    layout = Layout(x.shape[1], hidden, y.shape[1])
    theta0 = nguyen_widrow(layout, np.random.default_rng(0))
    empty = (xs[:0], ys[:0])
    options = LMOptions(goal_mse=1e-4, max_epochs=1000)
    _, ours = train_lm(layout, theta0, (xs, ys), empty, options)

    def residual(theta: F64) -> F64:
        out: F64 = (forward(layout, theta, xs).y - ys).ravel()
        return out

    start = time.perf_counter()
    ref = scipy.optimize.least_squares(
        residual, theta0, jac=lambda th: jacobian(layout, th, xs), method="lm",
        max_nfev=scipy_iterations)
    scipy_s = time.perf_counter() - start
    scipy_mse = float(np.mean(ref.fun**2))
    ours_it, scipy_it = ours.seconds_per_iteration, scipy_s / max(int(ref.njev), 1)
    return {"samples": int(x.shape[0]), "hidden": hidden, "params": layout.n_params,
            "ours_nit": ours.nit, "ours_mse": ours.mse, "ours_s": ours.elapsed_s,
            "ours_s_per_iteration": ours_it, "ours_message": ours.message,
            "scipy_njev": int(ref.njev), "scipy_mse": scipy_mse, "scipy_s": scipy_s,
            "scipy_s_per_iteration": scipy_it, "speedup_per_iteration": scipy_it / ours_it}


EXACT_PCT = 1e-6
"""An oracle below this floored error is exact (a noise-free test set): no ratio to it."""


def _floored(report: Any) -> float | None:
    return float(report.ave_rel_err_floored_pct) if report.floored else None


def cross_cell(decoded: Decoded, oracle: Decoded, force_N: F64, mode: str) -> dict[str, Any]:
    """One decoder on one test set: how much it flags, and its error where it does not,
    beside the oracle's on the same taxels and on all."""
    n = decoded.valid.size
    flagged = float(np.count_nonzero(decoded.reason == Reason.EXTRAPOLATED)) / max(n, 1)
    own = evaluate(force_N, decoded.force_N, decoded.valid, mode=mode)
    same = evaluate(force_N, oracle.force_N, decoded.valid & oracle.valid, mode=mode)
    mine, floor = _floored(own), _floored(same)
    return {"flagged_share": flagged,
            "invalid_share": float(np.count_nonzero(~decoded.valid)) / max(n, 1),
            "ave_rel_err_floored_pct": mine, "ave_rel_err_pct":
                None if mine is None else float(own.ave_rel_err_pct),
            "rmse_pct_fs": None if mine is None else float(own.rmse_pct_fs),
            "oracle_same_taxels_floored_pct": floor,
            "ratio_to_oracle": None if mine is None or floor is None or floor < EXACT_PCT
            else mine / floor,
            "compared": own.floored}


TestSet = tuple[F64, F64, F64]  # r, F, crosstalk M


def cross_matrix(
    train: dict[str, tuple[F64, F64]], test: dict[str, TestSet], mode: str,
    names: Sequence[str], *, params: Params | None = None, untrained: Sequence[str] = (),
) -> dict[str, Any]:
    """Every decoder fitted on every training set and decoded on every test set of one mode.

    ``untrained`` decoders (no fit) get one row per test set with ``train`` None."""
    oracles = {t: oracle_decode(r, m) for t, (r, _, m) in test.items()}
    oracle_rows = []
    for t, (_, f, _) in test.items():
        o = oracles[t]
        report = evaluate(f, o.force_N, o.valid, mode=mode)
        oracle_rows.append({"mode": mode, "test": t,
                            "ave_rel_err_floored_pct": float(report.ave_rel_err_floored_pct),
                            "ave_rel_err_pct": float(report.ave_rel_err_pct),
                            "rmse_pct_fs": float(report.rmse_pct_fs)})
    cells = []
    for name in names:
        sources: list[str | None] = [None] if name in untrained else list(train)
        for source in sources:
            decoder = create_decoder(name, **(params or {}).get(name, {}))
            start = time.perf_counter()
            if source is not None:
                decoder.fit(*train[source])
            fit_s = time.perf_counter() - start
            for t, (r, f, _) in test.items():
                cell = {"decoder": name, "mode": mode, "train": source, "test": t,
                        "seen": source == t, "train_s": fit_s}
                cell.update(cross_cell(decoder.decode(r), oracles[t], f, mode))
                cells.append(cell)
    return {"oracle": oracle_rows, "cells": cells}


def cross_bars(cells: Sequence[dict[str, Any]], *, hybrid_factor: float = 1.2,
               oracle_factor: float = 2.0) -> dict[str, list[dict[str, Any]]]:
    """issue 13's two checks on every unseen cell: hybrid against deconv (same train and
    test), and each trained decoder's unflagged error against the oracle's on those taxels.

    ``met`` is None where the oracle is exact (a noise-free test set): no factor of zero
    can be met, and the absolute errors are what to read there."""
    by = {(c["decoder"], c["mode"], c["train"], c["test"]): c for c in cells}
    hybrid, oracle = [], []
    for c in cells:
        if c["train"] is None or c["seen"]:
            continue
        mine = c["ave_rel_err_floored_pct"]
        if c["decoder"] == "hybrid":
            ref = by.get(("deconv", c["mode"], c["train"], c["test"]))
            theirs = None if ref is None else ref["ave_rel_err_floored_pct"]
            ratio = None if mine is None or not theirs else mine / theirs
            hybrid.append({"mode": c["mode"], "train": c["train"], "test": c["test"],
                           "hybrid": mine, "deconv": theirs, "ratio": ratio,
                           "met": ratio is None or ratio <= hybrid_factor})
        ratio, floor = c["ratio_to_oracle"], c["oracle_same_taxels_floored_pct"]
        exact = floor is not None and floor < EXACT_PCT
        oracle.append({"decoder": c["decoder"], "mode": c["mode"], "train": c["train"],
                       "test": c["test"], "error": mine, "oracle": floor, "ratio": ratio,
                       "compared": c["compared"], "flagged_share": c["flagged_share"],
                       "met": None if exact else
                       mine is None or (ratio is not None and ratio <= oracle_factor)})
    return {"hybrid_vs_deconv": hybrid, "unflagged_vs_oracle": oracle}
