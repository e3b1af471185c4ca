"""The ``analytic`` decoder: the exact inverse of the sensor model, per taxel, no training.

z-only input (P = 1) assumes a pure normal load (the paper's protocol) and uses
the tabulated exact inverse (decoder.ztable); 3-axis input (P = 3) uses the
closed-form tripod inverse (decoder.tripod3).
"""

from __future__ import annotations

from typing import Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from decoder.protocol import F64, BaseDecoder, Decoded, Progress, fold_resistance, unfold
from decoder.reasons import Reason, classify_resistance, saturation_ohm, worst_reason
from decoder.tripod3 import tripod_force_from_ratio_change
from decoder.ztable import normal_table
from skin.constants import SensorConstants


def ratio_change(r: F64, r0: F64) -> F64:
    """q = R/R0 - 1, computed as R·(1/R0) - 1 in one pass; non-finite R stays non-finite."""
    q = np.multiply(r, 1.0 / r0)
    q -= 1.0
    return q


def _reasons(r: F64, in_range: NDArray[np.bool_], constants: SensorConstants) -> NDArray[np.uint8]:
    """Taxel reasons (n, 9) from pillar readings (n, 9, P) and the physics' in-range mask (n, 9)."""
    reason = np.zeros(in_range.shape, dtype=np.uint8)
    bad = np.flatnonzero(~in_range)
    if bad.size:
        rows = r.reshape(-1, r.shape[-1])[bad]
        code = worst_reason(classify_resistance(rows, constants))
        reason.reshape(-1)[bad] = np.where(code == 0, np.uint8(Reason.OUT_OF_RANGE), code)
    return reason


def exact_inverse(
    r: F64, constants: SensorConstants, r0: F64
) -> tuple[F64, NDArray[np.uint8]]:
    """Resistances (n, 9, P) -> forces (n, 9, 3) and reasons (n, 9); invalid taxels 0 N."""
    n, taxels, pillars = r.shape
    q = ratio_change(r, r0)
    sat = saturation_ohm(constants)
    force = np.zeros((n, taxels, 3))
    if pillars == 1:
        table = normal_table(constants)
        fz, in_range = table.evaluate(q.reshape(-1))
        if np.any((1.0 + table.q_hi) * np.max(r0) >= sat):  # saturation inside the table's range
            in_range &= r.reshape(-1) < sat
        force[..., 2] = fz.reshape(n, taxels)
    else:
        f3, in_range = tripod_force_from_ratio_change(q.reshape(-1, 3), constants)
        if np.any((1.0 + constants.max_strain) ** 2 * np.max(r0) >= sat):
            in_range &= np.all(r.reshape(-1, 3) < sat, axis=1)
        force = f3.reshape(n, taxels, 3)
    in_range = in_range.reshape(n, taxels)
    reason = _reasons(r, in_range, constants)
    if reason.any():
        force[reason != 0] = 0.0
    return force, reason


class AnalyticDecoder(BaseDecoder):
    """Exact per-taxel inverse; ``fit`` only records nothing and returns self."""

    name = "analytic"

    def fit(self, resistance_ohm: ArrayLike, force_N: ArrayLike, *,
            progress: Progress | None = None) -> Self:
        fold_resistance(resistance_ohm)
        return self

    def decode(self, resistance_ohm: ArrayLike) -> Decoded:
        r, lead = fold_resistance(resistance_ohm)
        force, reason = exact_inverse(r, self.constants, self.r0_for(r.shape[-1]))
        return unfold(Decoded(force_N=force, valid=reason == 0, reason=reason), lead)

    def decode_unchecked(self, r: F64) -> tuple[F64, NDArray[np.uint8]]:
        """Folded (n, 9, P) float64 in, (force, reason) out: for decoders built on this one."""
        return exact_inverse(r, self.constants, self.r0_for(r.shape[-1]))
