"""The ``lm-mlp`` decoder: the paper's network, resistances in, forces out.

z-only: 9 resistances -> 9 normal forces; 3-axis: 27 -> 27 (Fx, Fy, Fz per taxel).
A taxel with a faulty pillar, or a reading outside the calibrated range (the
training range widened by ``range_margin`` of its span), is masked; its inputs
are replaced by the middle of the training range so the other taxels still
decode.
"""

from __future__ import annotations

from typing import Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from decoder.physics import to_force
from decoder.protocol import (
    F64,
    Progress,
    fold_force,
    fold_resistance,
)
from decoder.reasons import Reason, classify_resistance, worst_reason
from decoder.regressor import MLPDecoderBase, sample_rows
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.constants import TAXELS_PER_PATCH as T
from skin.errors import DecodeError


def targets(force: F64, pillars: int) -> F64:
    """Training targets (n, 9) Fz in z-only mode, (n, 27) all components in 3-axis mode."""
    return force[..., 2].copy() if pillars == 1 else force.reshape(force.shape[0], 3 * T)


class LMMLPDecoder(MLPDecoderBase):
    """Resistances -> one tanh hidden layer -> forces, trained by Levenberg-Marquardt."""

    name = "lm-mlp"
    _params = ("constants", "r0_ohm", "hidden", "goal_mse", "max_epochs", "val_fraction",
               "seed", "range_margin")

    def __init__(self, *, hidden: int = 10, goal_mse: float = 1e-4, max_epochs: int = 1000,
                 val_fraction: float = 0.15, seed: int = 0, range_margin: float = 0.1,
                 constants: SensorConstants = DEFAULT_CONSTANTS,
                 r0_ohm: ArrayLike | None = None) -> None:
        super().__init__(constants=constants, r0_ohm=r0_ohm, hidden=hidden, goal_mse=goal_mse,
                         max_epochs=max_epochs, val_fraction=val_fraction, seed=seed)
        if not range_margin >= 0.0:
            raise DecodeError(f"range_margin must be >= 0, got {range_margin!r}")
        self.range_margin = range_margin

    def fit(self, resistance_ohm: ArrayLike, force_N: ArrayLike, *,
            progress: Progress | None = None) -> Self:
        r, _ = fold_resistance(resistance_ohm)
        force = fold_force(force_N, r.shape[0])
        pillars = r.shape[-1]
        x = r.reshape(r.shape[0], -1)
        codes = worst_reason(classify_resistance(r, self.constants))
        keep = np.all(codes == 0, axis=1)
        self._fit_scaled(x[keep], targets(force[keep], pillars), pillars, progress)
        return self

    def _prepare(self) -> None:
        super()._prepare()
        margin = self.range_margin * (self.x_hi_ - self.x_lo_)
        self._lo, self._hi = self.x_lo_ - margin, self.x_hi_ + margin
        self._mid = 0.5 * (self.x_lo_ + self.x_hi_)

    def _decode_fast(self, r: F64) -> F64 | None:
        x = sample_rows(r)
        if not ((x >= self._lo) & (x <= self._hi)).all():
            return None
        return to_force(self._net(x), self.pillars_)

    def _decode_full(self, r: F64) -> tuple[F64, NDArray[np.uint8]]:
        x = sample_rows(r)
        reason = self._reasons(r, (x >= self._lo) & (x <= self._hi))
        bad = np.repeat(reason != 0, self.pillars_, axis=1).reshape(x.shape)
        x = np.where(bad, self._mid, x)
        return to_force(self._net(x), self.pillars_), reason

    def _reasons(self, r: F64, ok: NDArray[np.bool_]) -> NDArray[np.uint8]:
        in_range = ok.reshape(r.shape).all(axis=-1)
        code = worst_reason(classify_resistance(r, self.constants))
        return np.where((code == 0) & ~in_range, np.uint8(Reason.OUT_OF_RANGE), code)
