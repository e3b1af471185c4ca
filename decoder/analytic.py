"""The ``analytic`` decoder: the exact inverse of the sensor model, per taxel, no training.

z-only input (P = 1) assumes a pure normal load (the paper's protocol) and uses
the tabulated exact inverse (decoder.ztable); 3-axis input (P = 3) uses the
closed-form tripod inverse (decoder.tripod3). See decoder.physics.
"""

from __future__ import annotations

from typing import Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from decoder.physics import taxel_reasons, to_force
from decoder.protocol import F64, BaseDecoder, Progress, fold_resistance


class AnalyticDecoder(BaseDecoder):
    """Exact per-taxel inverse; ``fit`` learns nothing and returns self."""

    name = "analytic"

    def fit(self, resistance_ohm: ArrayLike, force_N: ArrayLike, *,
            progress: Progress | None = None) -> Self:
        fold_resistance(resistance_ohm)
        return self

    def _decode_fast(self, r: F64) -> F64 | None:
        pillars = r.shape[2]
        out = self.inverse(pillars).fast(r)
        return None if out is None else to_force(out, pillars)

    def _decode_full(self, r: F64) -> tuple[F64, NDArray[np.uint8]]:
        pillars = r.shape[2]
        out, ok = self.inverse(pillars).full(r)
        return to_force(out, pillars), taxel_reasons(r, ok, self.constants)
