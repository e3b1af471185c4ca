"""Levenberg-Marquardt training with MATLAB trainlm's semantics.

dX = -(JᵀJ + mu·I)⁻¹ Jᵀe by Cholesky; mu starts at 1e-3, is multiplied by
10 after a step that does not lower the training MSE and by 0.1 after one
that does; training stops at the goal MSE, when mu exceeds 1e10, when the
gradient vanishes, after ``max_fail`` consecutive validation rises (returning
the weights of the best validation epoch, as MATLAB does), or at
``max_epochs``.

The network works on scaled ([-1, 1]) outputs; the MSE that the goal, the
validation checks and the result report is of ``weight ⊙ error`` per output.
With ``weight`` the outputs' half-spans it is the MSE in the targets' own
units, as MATLAB's default performance function measures it; without, the MSE
on the scaled outputs.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from decoder.mlp import F64, Layout, forward, normal_equations, predict
from decoder.protocol import Progress

MU_FLOOR = 1e-20  # keeps repeated x0.1 from underflowing to 0 (MATLAB lets it run)


@dataclass(frozen=True)
class TrainResult:
    """Why and where training stopped (SciPy OptimizeResult's fields, frozen)."""

    success: bool
    message: str
    nit: int
    nfev: int
    mse: float
    mu: float
    elapsed_s: float
    val_mse: float
    best_epoch: int

    @property
    def seconds_per_iteration(self) -> float:
        return self.elapsed_s / max(self.nit, 1)


@dataclass(frozen=True)
class LMOptions:
    goal_mse: float = 1e-4
    max_epochs: int = 1000
    mu: float = 1e-3
    mu_dec: float = 0.1
    mu_inc: float = 10.0
    mu_max: float = 1e10
    max_fail: int = 6
    min_grad: float = 1e-7


def _mean_square(e: F64, weight: F64 | None) -> float:
    r = e if weight is None else e * weight
    return float(np.mean(r * r))


def _mse(layout: Layout, theta: F64, x: F64, t: F64, weight: F64 | None) -> float:
    if x.shape[0] == 0:
        return float("nan")
    with np.errstate(over="ignore", invalid="ignore"):
        value = _mean_square(predict(layout, theta, x) - t, weight)
    return value if np.isfinite(value) else float("inf")


def _step(jtj: F64, g: F64, mu: float) -> F64 | None:
    """Solve (JᵀJ + mu I) dX = -g; None when the matrix is not positive definite."""
    a = jtj.copy()
    a.flat[:: a.shape[0] + 1] += mu
    try:
        factor = scipy.linalg.cho_factor(a, lower=False, check_finite=False)
    except np.linalg.LinAlgError:
        return None
    dx: F64 = -scipy.linalg.cho_solve(factor, g, check_finite=False)
    return dx if np.all(np.isfinite(dx)) else None


def train_lm(
    layout: Layout,
    theta: F64,
    train: tuple[F64, F64],
    val: tuple[F64, F64],
    options: LMOptions = LMOptions(),
    progress: Progress | None = None,
    weight: F64 | None = None,
) -> tuple[F64, TrainResult]:
    """Train from ``theta`` on scaled (inputs, targets); returns the weights and a TrainResult.

    ``weight`` (O,) multiplies each output's error before it is squared (see above).
    """
    start = time.perf_counter()
    x, t = train
    xv, tv = val
    theta = np.array(theta, dtype=np.float64)
    mu = options.mu
    nfev = 1
    with np.errstate(over="ignore", invalid="ignore"):
        fw = forward(layout, theta, x)
        e = fw.y - t
        mse = _mean_square(e, weight)
    best_theta, best_val, best_epoch = theta.copy(), _mse(layout, theta, xv, tv, weight), 0
    fails = 0
    epoch = 0
    while True:
        if not np.isfinite(mse):
            message = "training MSE is not finite at the starting point"
            break
        jtj, g = normal_equations(layout, theta, fw, e, weight)
        grad = 2.0 * float(np.linalg.norm(g)) / e.size
        if mse <= options.goal_mse:
            message = "performance goal met"
            break
        if mu > options.mu_max:
            message = f"mu exceeded its maximum of {options.mu_max:g}"
            break
        if grad < options.min_grad:
            message = "minimum gradient reached"
            break
        if fails >= options.max_fail:
            message = f"validation stop: {fails} consecutive rises"
            break
        if epoch >= options.max_epochs:
            message = "maximum epochs reached"
            break
        epoch += 1
        while mu <= options.mu_max:
            dx = _step(jtj, g, mu)
            if dx is not None:
                trial = theta + dx
                nfev += 1
                with np.errstate(over="ignore", invalid="ignore"):
                    fw_trial = forward(layout, trial, x)
                    e_trial = fw_trial.y - t
                    mse_trial = _mean_square(e_trial, weight)
                if np.isfinite(mse_trial) and mse_trial < mse:
                    theta, fw, e, mse = trial, fw_trial, e_trial, mse_trial
                    mu = max(mu * options.mu_dec, MU_FLOOR)
                    break
            mu *= options.mu_inc
        if xv.shape[0]:
            val_mse = _mse(layout, theta, xv, tv, weight)
            nfev += 1
            if val_mse < best_val:
                best_theta, best_val, best_epoch, fails = theta.copy(), val_mse, epoch, 0
            elif val_mse > best_val:
                fails += 1
        if progress is not None:
            progress(epoch, mse, mu)
    if xv.shape[0] == 0:
        best_theta, best_epoch = theta, epoch
    elif message.startswith("validation stop") or _mse(layout, theta, xv, tv, weight) > best_val:
        theta = best_theta
    else:
        best_epoch = epoch
    final_mse = _mse(layout, theta, x, t, weight)
    success = message.startswith(("performance goal", "validation stop", "minimum gradient"))
    result = TrainResult(
        success=success, message=message, nit=epoch, nfev=nfev, mse=final_mse, mu=mu,
        elapsed_s=time.perf_counter() - start,
        val_mse=_mse(layout, theta, xv, tv, weight) if xv.shape[0] else float("nan"),
        best_epoch=best_epoch,
    )
    return theta, result
