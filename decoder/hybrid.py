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
from numpy.typing import ArrayLike

from decoder.analytic import exact_inverse
from decoder.lmmlp import targets, to_force
from decoder.protocol import (
    Decoded,
    Progress,
    fold_force,
    fold_resistance,
    unfold,
)
from decoder.regressor import MLPDecoderBase
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.errors import DecodeError


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
        physics, reason = exact_inverse(r, self.constants, self.r0_for(pillars))
        keep = np.all(reason == 0, axis=1)
        x = targets(physics[keep], pillars)
        self._fit_scaled(x, targets(force[keep], pillars) - x, pillars, progress)
        return self

    def decode(self, resistance_ohm: ArrayLike) -> Decoded:
        self._require_fitted()
        r, lead = fold_resistance(resistance_ohm)
        if r.shape[-1] != self.pillars_:
            raise DecodeError(f"model was fitted on {self.pillars_}-pillar input, "
                              f"got {r.shape[-1]} pillars")
        physics, reason = exact_inverse(r, self.constants, self.r0_for(self.pillars_))
        x = targets(physics, self.pillars_)
        correction = self._net(np.clip(x, self.x_lo_, self.x_hi_))
        force = to_force(x + correction, self.pillars_)
        valid = reason == 0
        if not valid.all():
            force[~valid] = 0.0
        return unfold(Decoded(force_N=force, valid=valid, reason=reason), lead)
