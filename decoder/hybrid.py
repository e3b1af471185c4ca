"""The ``hybrid`` decoder: physics features into a small LM-trained MLP that learns the residual.

Features are the analytic decoder's forces (9 Fz in z-only mode, 27 components
in 3-axis mode); the network learns true minus analytic (crosstalk, model
error) and its output is added back. Features are clamped to the training
range before the network, so outside it the physics still extrapolates and
the learned correction does not.
"""

from __future__ import annotations

from typing import Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from decoder.lmmlp import targets
from decoder.physics import solve, taxel_reasons, to_force
from decoder.protocol import (
    F64,
    Progress,
    fold_force,
    fold_resistance,
)
from decoder.regressor import MLPDecoderBase, sample_rows
from skin.constants import DEFAULT_CONSTANTS, SensorConstants


class HybridDecoder(MLPDecoderBase):
    """Analytic forces plus an MLP-learned residual."""

    name = "hybrid"
    _params = ("constants", "r0_ohm", "hidden", "goal_mse", "max_epochs", "val_fraction", "seed")

    def __init__(self, *, constants: SensorConstants = DEFAULT_CONSTANTS,
                 r0_ohm: ArrayLike | None = None, hidden: int = 12, goal_mse: float = 1e-4,
                 max_epochs: int = 300, val_fraction: float = 0.15, seed: int = 0) -> None:
        super().__init__(constants=constants, r0_ohm=r0_ohm, hidden=hidden, goal_mse=goal_mse,
                         max_epochs=max_epochs, val_fraction=val_fraction, seed=seed)

    def fit(self, resistance_ohm: ArrayLike, force_N: ArrayLike, *,
            progress: Progress | None = None) -> Self:
        r, _ = fold_resistance(resistance_ohm)
        force = fold_force(force_N, r.shape[0])
        pillars = r.shape[-1]
        physics, reason = solve(self.inverse(pillars), r, self.constants)
        keep = np.all(reason == 0, axis=1)
        x = targets(physics[keep], pillars)
        self._fit_scaled(x, targets(force[keep], pillars) - x, pillars, progress)
        return self

    def _predict(self, physics: F64) -> F64:
        """Analytic outputs (Fz (n, 9) or forces (n, 9, 3)) -> corrected forces (n, 9, 3)."""
        x = sample_rows(physics)
        y = self._net(np.minimum(np.maximum(x, self.x_lo_), self.x_hi_))
        y += x
        return to_force(y, self.pillars_)

    def _decode_fast(self, r: F64) -> F64 | None:
        physics = self.inverse(self.pillars_).fast(r)
        return None if physics is None else self._predict(physics)

    def _decode_full(self, r: F64) -> tuple[F64, NDArray[np.uint8]]:
        physics, ok = self.inverse(self.pillars_).full(r)  # 0 N where not ok
        return self._predict(physics), taxel_reasons(r, ok, self.constants)
