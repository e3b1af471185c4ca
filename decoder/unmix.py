"""The crosstalk inverse W ≈ M⁻¹, calibrated from data: a kernel first, then the full matrix.

The rubber spreads force to neighbours, F_eff = M F per component. Two fits:

1. **Kernel.** M = (1 + g)·I + c·(4-neighbours) + d·(diagonal neighbours): three numbers,
   well determined by any data with a load on it, even one press repeated, because the
   side and diagonal neighbours of a loaded taxel see different shares.
2. **Full 9x9 W**, by least squares with Tikhonov regularisation towards the kernel's
   inverse W_k::

       W = argmin ||F_eff W' - F||² + lam ||W - W_k||²,  lam = alpha · trace(F_effᵀ F_eff) / 9

   Where the data vary, the data decide (edge effects, uneven rubber); where they never
   vary (a slide along one line, five grasps), W stays at the kernel's inverse instead of
   fitting noise. Regularising towards I instead (no unmixing) would leave those
   directions with the full crosstalk error.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from skin.errors import DecodeError

F64 = NDArray[np.float64]

PRIOR_DAMPING = 1e-4
"""The kernel's inverse is damped along directions with singular values below 1 % of the
largest; the simulator's crosstalk has its smallest at 76 % of its largest."""


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


def damped_inverse(m: F64) -> F64:
    """(MᵀM + εI)⁻¹Mᵀ with ε = PRIOR_DAMPING · σ_max²: M⁻¹ where M is well conditioned, and
    no huge gains along directions M nearly annihilates (there noise would be amplified)."""
    u, sigma, vt = np.linalg.svd(m)
    eps = PRIOR_DAMPING * float(sigma[0]) ** 2
    inverse: F64 = (vt.T * (sigma / (sigma * sigma + eps))) @ u.T
    return inverse


def fit_unmix(effective: F64, force: F64, alpha: float) -> F64:
    """W (9, 9) with F ≈ F_eff @ W.T, from rows (m, 9), regularised towards the kernel's inverse."""
    kernel = kernel_matrix(*fit_kernel(effective, force))
    prior = damped_inverse(kernel) if np.all(np.isfinite(kernel)) else np.eye(9)
    gram = effective.T @ effective
    lam = alpha * max(float(np.trace(gram)) / 9, 1e-300)
    rhs = effective.T @ force + lam * prior.T
    gram.flat[::10] += lam
    try:
        wt = scipy.linalg.cho_solve(scipy.linalg.cho_factor(gram), rhs)
    except np.linalg.LinAlgError as err:
        raise DecodeError("the calibration data give no usable crosstalk inverse") from err
    return np.ascontiguousarray(wt.T)
