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
from decoder.lm import LMOptions, TrainResult
from decoder.lmmlp import targets, to_force
from decoder.mlp import Layout
from decoder.protocol import (
    F64,
    BaseDecoder,
    Decoded,
    Progress,
    expect_array,
    fold_force,
    fold_resistance,
    unfold,
)
from decoder.regressor import FoldedMLP, fit_mlp
from skin.constants import DEFAULT_CONSTANTS, TAXELS_PER_PATCH, SensorConstants
from skin.errors import DecodeError, ModelFileError


class HybridDecoder(BaseDecoder):
    """Analytic forces plus an MLP-learned residual."""

    name = "hybrid"
    _params = ("constants", "r0_ohm", "hidden", "goal_mse", "max_epochs", "val_fraction", "seed")
    _state = ("pillars_", "x_lo_", "x_hi_", "y_lo_", "y_hi_", "theta_")

    pillars_: int
    x_lo_: F64
    x_hi_: F64
    y_lo_: F64
    y_hi_: F64
    theta_: F64
    train_result_: TrainResult

    def __init__(self, *, constants: SensorConstants = DEFAULT_CONSTANTS,
                 r0_ohm: ArrayLike | None = None, hidden: int = 12, goal_mse: float = 1e-4,
                 max_epochs: int = 300, val_fraction: float = 0.15, seed: int = 0) -> None:
        super().__init__(constants=constants, r0_ohm=r0_ohm)
        if not (isinstance(hidden, int) and 1 <= hidden <= 1000):
            raise DecodeError(f"hidden must be an integer in [1, 1000], got {hidden!r}")
        if not (0.0 <= val_fraction < 1.0 and goal_mse >= 0.0 and max_epochs >= 0):
            raise DecodeError("val_fraction in [0, 1), goal_mse >= 0, max_epochs >= 0 required")
        self.hidden, self.goal_mse, self.max_epochs = hidden, goal_mse, max_epochs
        self.val_fraction, self.seed = val_fraction, seed

    def _layout(self) -> Layout:
        n = TAXELS_PER_PATCH * (1 if self.pillars_ == 1 else 3)
        return Layout(n, self.hidden, n)

    def fit(self, resistance_ohm: ArrayLike, force_N: ArrayLike, *,
            progress: Progress | None = None) -> Self:
        r, _ = fold_resistance(resistance_ohm)
        force = fold_force(force_N, r.shape[0])
        pillars = r.shape[-1]
        physics, reason = exact_inverse(r, self.constants, self.r0_for(pillars))
        keep = np.all(reason == 0, axis=1)
        x = targets(physics[keep], pillars)
        y = targets(force[keep], pillars) - x
        options = LMOptions(goal_mse=self.goal_mse, max_epochs=self.max_epochs)
        state, self.train_result_ = fit_mlp(x, y, hidden=self.hidden, options=options,
                                            val_fraction=self.val_fraction, seed=self.seed,
                                            progress=progress)
        for key, value in state.items():
            setattr(self, key, value)
        self.pillars_ = pillars
        self._net = FoldedMLP(self._layout(), state)
        return self

    @property
    def train_result(self) -> TrainResult | None:
        return getattr(self, "train_result_", None)

    def _check_state(self) -> None:
        if self.pillars_ not in (1, 3) or isinstance(self.pillars_, bool):
            raise ModelFileError(f"state.pillars_: must be 1 or 3, got {self.pillars_!r}")
        layout = self._layout()
        for key in ("x_lo_", "x_hi_"):
            expect_array(getattr(self, key), key, (layout.n_in,))
        for key in ("y_lo_", "y_hi_"):
            expect_array(getattr(self, key), key, (layout.n_out,))
        expect_array(self.theta_, "theta_", (layout.n_params,))
        state = {k: getattr(self, k) for k in ("x_lo_", "x_hi_", "y_lo_", "y_hi_", "theta_")}
        self._net = FoldedMLP(layout, state)

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
