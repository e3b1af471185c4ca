"""Per-feature bounds and whitening: what a decoder's domain checks are built from.

:mod:`decoder.domain` (the whole training domain) and :mod:`decoder.patchcheck` (the checks of
a whole patch) both use them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from skin.errors import ModelFileError

F64 = NDArray[np.float64]
Mask = NDArray[np.bool_]

RIDGE = 1e-6
"""Added to the standardised covariance's diagonal: directions with less than about 0.1 % of
a feature's spread are taken as never visited."""


def expect_array(value: Any, field: str, shape: tuple[int, ...]) -> F64:
    """``value`` if it is a float64 array of ``shape``, else a ModelFileError naming ``field``."""
    if not isinstance(value, np.ndarray) or value.dtype != np.float64 or value.shape != shape:
        got = value.shape if isinstance(value, np.ndarray) else type(value).__name__
        raise ModelFileError(f"{field}: expected float64 array of shape {shape}, got {got}")
    return value


@dataclass(frozen=True)
class Box:
    """Per-feature bounds (k,), margins included.

    A value is inside when |x - mid| <= half, one formula for the mask and the quick test,
    so that they agree to the last bit; NaN is outside and infinities never overflow."""

    lo: F64
    hi: F64

    def __post_init__(self) -> None:
        object.__setattr__(self, "_mid", 0.5 * self.lo + 0.5 * self.hi)
        object.__setattr__(self, "_half", 0.5 * self.hi - 0.5 * self.lo)

    @classmethod
    def fit(cls, x: F64, margin: float) -> Box:
        lo, hi = x.min(axis=0), x.max(axis=0)
        widen = margin * float(np.max(hi - lo))
        return cls(lo - widen, hi + widen)

    def inside(self, x: F64) -> Mask:
        """Elementwise: (n, k) or (k,) -> same shape; NaN is outside."""
        inside: Mask = np.abs(x - self._mid) <= self._half  # type: ignore[attr-defined]
        return inside

    def all_inside(self, x: F64) -> bool:
        """Whether every value is inside (False for any NaN)."""
        return bool(self.inside(x).all())

    def clamp(self, x: F64) -> F64:
        clamped: F64 = np.minimum(np.maximum(x, self.lo), self.hi)
        return clamped

    def to_state(self) -> dict[str, F64]:
        return {"lo": self.lo, "hi": self.hi}

    @classmethod
    def from_state(cls, state: Any, field: str, size: int) -> Box:
        if not isinstance(state, dict) or set(state) != {"lo", "hi"}:
            raise ModelFileError(f"{field}: expected a map with keys ['hi', 'lo']")
        lo = expect_array(state["lo"], f"{field}.lo", (size,))
        hi = expect_array(state["hi"], f"{field}.hi", (size,))
        if np.any(lo > hi):
            raise ModelFileError(f"{field}: a range has lo > hi")
        return cls(lo, hi)


def whitening(x: F64) -> tuple[F64, F64]:
    """Mean (k,) and upper-triangular ``whiten`` (k, k) such that (x - mean) @ whiten has
    identity covariance over the rows of ``x`` (n, k): standardised, with a ridge of
    ``RIDGE`` on the covariance."""
    mean = x.mean(axis=0)
    centred = x - mean
    scale = centred.std(axis=0)
    scale = np.maximum(scale, 1e-12 * max(float(scale.max()), 1e-300))
    z = centred / scale
    cov = z.T @ z / max(x.shape[0] - 1, 1)
    cov.flat[:: cov.shape[0] + 1] += RIDGE
    upper = scipy.linalg.cholesky(cov, lower=False)  # cov = Uᵀ U
    # (x - mean) / scale @ U⁻¹ has identity covariance.
    whiten = scipy.linalg.solve_triangular(upper, np.eye(cov.shape[0]), lower=False)
    return mean, np.ascontiguousarray(whiten / scale[:, None])
