"""The ``deconv`` decoder: the exact inverse, then a crosstalk inverse calibrated from data.

The rubber spreads force to neighbours, F_eff = M F per component. Given the
analytic forces F_eff and the true forces F of a calibration set, W ≈ M⁻¹ is
fit by least squares with Tikhonov regularisation towards the identity::

    W = argmin ||F_eff W' - F||² + lam ||W - I||²,  lam = alpha · trace(F_effᵀ F_eff) / 9

so a near-singular crosstalk (or too little data) gives a stable, finite W.
Invalid taxels enter the deconvolution as 0 N; their neighbours still decode.
"""

from __future__ import annotations

from typing import Self

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from decoder.physics import solve, taxel_reasons, to_force
from decoder.protocol import (
    F64,
    BaseDecoder,
    Progress,
    expect_array,
    fold_force,
    fold_resistance,
)
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.errors import DecodeError, ModelFileError


def fit_tikhonov(a: F64, b: F64, alpha: float) -> F64:
    """W (9, 9) with b ≈ a @ W.T, regularised towards the identity."""
    gram = a.T @ a
    lam = alpha * max(float(np.trace(gram)) / a.shape[1], 1e-300)
    rhs = a.T @ b + lam * np.eye(a.shape[1])
    gram.flat[:: gram.shape[0] + 1] += lam
    wt = scipy.linalg.cho_solve(scipy.linalg.cho_factor(gram), rhs)
    return np.ascontiguousarray(wt.T)


class DeconvDecoder(BaseDecoder):
    """Analytic per-taxel inverse followed by a calibrated 9x9 crosstalk inverse."""

    name = "deconv"
    _params = ("constants", "r0_ohm", "alpha")
    _state = ("pillars_", "unmix_")
    pillars_: int
    unmix_: F64

    def __init__(self, *, constants: SensorConstants = DEFAULT_CONSTANTS,
                 r0_ohm: ArrayLike | None = None, alpha: float = 1e-6) -> None:
        super().__init__(constants=constants, r0_ohm=r0_ohm)
        if not (isinstance(alpha, float | int) and 0.0 < alpha < 1e6):
            raise DecodeError(f"alpha must be in (0, 1e6), got {alpha!r}")
        self.alpha = float(alpha)

    def fit(self, resistance_ohm: ArrayLike, force_N: ArrayLike, *,
            progress: Progress | None = None) -> Self:
        r, _ = fold_resistance(resistance_ohm)
        force = fold_force(force_N, r.shape[0])
        effective, reason = solve(self.inverse(r.shape[-1]), r, self.constants)
        keep = np.all(reason == 0, axis=1)
        if not np.any(keep):
            raise DecodeError("no calibration sample has all nine taxels valid")
        comps = [2] if r.shape[-1] == 1 else [0, 1, 2]
        a = np.concatenate([effective[keep][..., c] for c in comps])
        b = np.concatenate([force[keep][..., c] for c in comps])
        self.unmix_ = fit_tikhonov(a, b, self.alpha)
        self.pillars_ = r.shape[-1]
        return self

    def _check_state(self) -> None:
        expect_array(self.unmix_, "unmix_", (9, 9))
        if self.pillars_ not in (1, 3) or isinstance(self.pillars_, bool):
            raise ModelFileError(f"state.pillars_: must be 1 or 3, got {self.pillars_!r}")

    def _unmix(self, effective: F64) -> F64:
        """W applied per sample and component: Fz (n, 9) or forces (n, 9, 3) -> forces."""
        if effective.ndim == 2:
            return to_force(effective @ self.unmix_.T, 1)
        force: F64 = np.matmul(self.unmix_, effective)
        return force

    def _decode_fast(self, r: F64) -> F64 | None:
        effective = self.inverse(self.pillars_).fast(r)
        return None if effective is None else self._unmix(effective)

    def _decode_full(self, r: F64) -> tuple[F64, NDArray[np.uint8]]:
        effective, ok = self.inverse(self.pillars_).full(r)  # 0 N where not ok
        return self._unmix(effective), taxel_reasons(r, ok, self.constants)
