"""Speed against error: the measurements behind ``skin bench``.

Pure functions of arrays (the command builds the datasets with the simulator):
fit time, batched decode throughput, single-sample latency, accuracy against
the oracle, the paper's Table 1 sweep, and LM against SciPy per iteration.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import scipy.optimize

from decoder.lm import LMOptions, train_lm
from decoder.metrics import evaluate
from decoder.mlp import F64, Layout, forward, jacobian, mapminmax, minmax_range, nguyen_widrow
from decoder.oracle import oracle_decode
from decoder.protocol import Decoder
from decoder.registry import create_decoder

Split = tuple[F64, F64, F64, F64]  # train r, train F, test r, test F


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


def bench_decoders(
    splits: Sequence[Split], crosstalk: F64, mode: str, names: Sequence[str], *,
    batch: int, repeats: int,
) -> dict[str, Any]:
    """Accuracy (mean over splits) and speed of every decoder, plus the oracle."""
    oracle = [oracle_decode(s[2], crosstalk) for s in splits]
    reports = [evaluate(s[3], o.force_N, o.valid, mode=mode) for s, o in zip(splits, oracle,
                                                                             strict=True)]
    out: dict[str, Any] = {"oracle": {
        key: float(np.mean([getattr(r, key) for r in reports]))
        for key in ("ave_rel_err_pct", "ave_rel_err_floored_pct", "rmse_pct_fs")}}
    rows = []
    for name in names:
        fits, errs, decoder = [], [], None
        for r_train, f_train, r_test, f_test in splits:
            decoder = create_decoder(name)
            start = time.perf_counter()
            decoder.fit(r_train, f_train)
            fits.append(time.perf_counter() - start)
            decoded = decoder.decode(r_test)
            errs.append(evaluate(f_test, decoded.force_N, decoded.valid, mode=mode))
        assert decoder is not None
        rate, latency = decode_speed(decoder, splits[0][2], batch, repeats)
        row: dict[str, Any] = {"name": name}
        for key in ("ave_rel_err_pct", "ave_rel_err_floored_pct", "rmse_pct_fs",
                    "max_rel_err_floored_pct"):
            row[key] = float(np.mean([getattr(e, key) for e in errs]))
        row.update(train_s=float(np.mean(fits)), decode_samples_per_s=rate, latency_us=latency)
        rows.append(row)
    out["decoders"] = rows
    return out


def table1(splits: Sequence[Split], mode: str, scene: str,
           hidden: Sequence[int] = tuple(range(5, 15))) -> list[dict[str, Any]]:
    """The paper's Table 1: lm-mlp AveRelErr by hidden nodes, mean over splits."""
    rows = []
    for h in hidden:
        errs = []
        for r_train, f_train, r_test, f_test in splits:
            decoder = create_decoder("lm-mlp", hidden=h).fit(r_train, f_train)
            decoded = decoder.decode(r_test)
            errs.append(evaluate(f_test, decoded.force_N, decoded.valid, mode=mode))
        rows.append({"scene": scene, "hidden": h,
                     "ave_rel_err_pct": float(np.mean([e.ave_rel_err_pct for e in errs])),
                     "ave_rel_err_floored_pct":
                         float(np.mean([e.ave_rel_err_floored_pct for e in errs]))})
    return rows


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
