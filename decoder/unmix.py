"""The crosstalk inverse W ≈ M⁻¹, calibrated from data: a kernel first, then the full matrix.

The rubber spreads force to neighbours, F_eff = M F per component. Two fits:

1. **Kernel.** M = (1 + g)·I + c·(4-neighbours) + d·(diagonal neighbours): three numbers,
   well determined by any data with a load on it, even one press repeated, because the
   side and diagonal neighbours of a loaded taxel see different shares.
2. **Full 9x9 W**, by least squares with Tikhonov regularisation towards the kernel's
   inverse W_k::

       W = argmin ||F_eff W' - F||² + lam ||W - W_k||²,  lam = alpha · trace(F_effᵀ F_eff) / 9

   Where the data vary, the data decide (edge effects, uneven rubber); where they barely
   vary (a slide along one line, five grasps), W leans on the kernel's inverse.
   Regularising towards I instead (no unmixing) would leave those directions with the
   whole crosstalk error.

Both are fitted on 85 % of the rows and compared on the other 15 %: the full W is used
only if it lowers the validation error by ``FULL_GAIN``. Otherwise the kernel explains the
data about as well, and its inverse is used. On a load distribution with strongly
correlated taxels the full W always wins a little on held-out rows of the same
distribution, because a regression uses the correlation to average out noise (13 % on
`slide`, 16 % on `grasp`); that gain does not transfer, and the full W's 78 extra numbers,
fitted along directions the calibration barely excited, cost accuracy on any other load
distribution (7-12 % floored error instead of 3-4 % when trained on `slide` or `grasp`
and tested on `indenter` or `paper-noisy`, ``skin bench cross``). A real departure from a
kernel (uneven rubber, edges) is a systematic error and wins by far more than 25 %.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from skin.errors import DecodeError

F64 = NDArray[np.float64]



def _neighbours() -> tuple[F64, F64]:
    row, col = np.divmod(np.arange(9), 3)
    dr = np.abs(row[:, None] - row[None, :])
    dc = np.abs(col[:, None] - col[None, :])
    side = (dr + dc == 1).astype(np.float64)
    diagonal = ((dr == 1) & (dc == 1)).astype(np.float64)
    return side, diagonal


SIDE, DIAGONAL = _neighbours()


def kernel_matrix(gain: float, side: float, diagonal: float) -> F64:
    """M = (1 + gain)·I + side·(4-neighbours) + diagonal·(diagonal neighbours)."""
    m: F64 = (1.0 + gain) * np.eye(9) + side * SIDE + diagonal * DIAGONAL
    return m


def fit_kernel(effective: F64, force: F64) -> tuple[float, float, float]:
    """(gain, side, diagonal) from rows of F_eff (m, 9) and F (m, 9), least squares."""
    columns = np.stack((force, force @ SIDE.T, force @ DIAGONAL.T), axis=-1).reshape(-1, 3)
    target = (effective - force).reshape(-1)
    if not np.any(columns):
        return 0.0, 0.0, 0.0
    coef, *_ = np.linalg.lstsq(columns, target, rcond=None)
    return float(coef[0]), float(coef[1]), float(coef[2])


def damped_inverse(m: F64, eps: float) -> F64:
    """(MᵀM + εI)⁻¹Mᵀ: M⁻¹ where M is well conditioned, and no huge gains along directions M
    nearly annihilates, where they would only amplify noise (a Wiener inverse when ε is the
    noise-to-signal power ratio)."""
    u, sigma, vt = np.linalg.svd(m)
    inverse: F64 = (vt.T * (sigma / (sigma * sigma + eps))) @ u.T
    return inverse


FULL_GAIN = 0.25


@dataclass(frozen=True)
class Unmix:
    """The crosstalk inverse and how it was chosen."""

    matrix: F64
    model: str  # "kernel" or "full"
    kernel: tuple[float, float, float]
    val_mse_kernel: float
    val_mse_full: float

    def to_meta(self) -> dict[str, Any]:
        gain, side, diagonal = self.kernel
        return {"model": self.model, "kernel_gain": gain, "kernel_side": side,
                "kernel_diagonal": diagonal, "val_mse_kernel_N2": self.val_mse_kernel,
                "val_mse_full_N2": self.val_mse_full, "required_gain": FULL_GAIN}


def kernel_inverse(effective: F64, force: F64) -> tuple[F64, tuple[float, float, float]]:
    """The kernel fitted on rows (m, 9) and its Wiener inverse: damped by the ratio of the
    kernel's residual power (noise) to the forces' power."""
    params = fit_kernel(effective, force)
    kernel = kernel_matrix(*params)
    if not np.all(np.isfinite(kernel)):
        return np.eye(9), params
    noise = _mse(effective - force @ kernel.T)
    signal = _mse(force)
    eps = noise / signal if signal > 0 else 0.0
    return damped_inverse(kernel, max(eps, 1e-15)), params


def fit_unmix(effective: F64, force: F64, alpha: float) -> Unmix:
    """W (9, 9) with F ≈ F_eff @ W.T from rows (m, 9): the kernel's inverse, or the full W if
    it predicts the held-out rows better by FULL_GAIN."""
    rows = np.random.default_rng(0).permutation(effective.shape[0])
    n_val = effective.shape[0] * 15 // 100
    val, train = rows[:n_val], rows[n_val:]
    if n_val < 9:
        val = train = rows
    prior, _ = kernel_inverse(effective[train], force[train])
    full = fit_full(effective[train], force[train], alpha, prior)
    mse_kernel = _mse(effective[val] @ prior.T - force[val])
    mse_full = _mse(effective[val] @ full.T - force[val])
    prior, params = kernel_inverse(effective, force)
    resolvable = mse_kernel > 1e-12 * _mse(force)  # else both are exact to rounding
    if resolvable and mse_full < (1.0 - FULL_GAIN) * mse_kernel:
        return Unmix(fit_full(effective, force, alpha, prior), "full", params, mse_kernel,
                     mse_full)
    return Unmix(np.ascontiguousarray(prior), "kernel", params, mse_kernel, mse_full)


def _mse(e: F64) -> float:
    return float(np.mean(e * e)) if e.size else 0.0


def fit_full(effective: F64, force: F64, alpha: float, prior: F64) -> F64:
    """W (9, 9) by least squares regularised towards ``prior``."""
    gram = effective.T @ effective
    lam = alpha * max(float(np.trace(gram)) / 9, 1e-300)
    rhs = effective.T @ force + lam * prior.T
    gram.flat[::10] += lam
    try:
        wt = scipy.linalg.cho_solve(scipy.linalg.cho_factor(gram), rhs)
    except np.linalg.LinAlgError as err:
        raise DecodeError("the calibration data give no usable crosstalk inverse") from err
    return np.ascontiguousarray(wt.T)


def unmix_rows(effective: F64, force: F64, pillars: int) -> tuple[F64, F64]:
    """Per-component rows (m, 9) of analytic and true forces (n, 9, 3) for :func:`fit_unmix`:
    Fz alone in z-only mode, Fx, Fy and Fz stacked in 3-axis mode (one W for all three)."""
    comps = [2] if pillars == 1 else [0, 1, 2]
    return (np.concatenate([effective[..., c] for c in comps]),
            np.concatenate([force[..., c] for c in comps]))


def apply_unmix(unmix: F64, effective: F64) -> F64:
    """W per sample and component: Fz (n, 9) -> (n, 9), forces (n, 9, 3) -> (n, 9, 3)."""
    if effective.ndim == 2:
        fz: F64 = effective @ unmix.T
        return fz
    force: F64 = np.matmul(unmix, effective)
    return force
