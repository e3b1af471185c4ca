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

from decoder.lm import LMOptions, TrainResult
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
from decoder.reasons import Reason, classify_resistance, worst_reason
from decoder.regressor import FoldedMLP, fit_mlp
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.constants import TAXELS_PER_PATCH as T
from skin.errors import DecodeError, ModelFileError


def targets(force: F64, pillars: int) -> F64:
    """Training targets (n, 9) Fz in z-only mode, (n, 27) all components in 3-axis mode."""
    return force[..., 2].copy() if pillars == 1 else force.reshape(force.shape[0], 3 * T)


def to_force(y: F64, pillars: int) -> F64:
    if pillars == 3:
        return y.reshape(-1, T, 3)
    force = np.zeros((y.shape[0], T, 3))
    force[..., 2] = y
    return force


class LMMLPDecoder(BaseDecoder):
    """Resistances -> one tanh hidden layer -> forces, trained by Levenberg-Marquardt."""

    name = "lm-mlp"
    _params = ("constants", "r0_ohm", "hidden", "goal_mse", "max_epochs", "val_fraction",
               "seed", "range_margin")
    _state = ("pillars_", "x_lo_", "x_hi_", "y_lo_", "y_hi_", "theta_")

    pillars_: int
    x_lo_: F64
    x_hi_: F64
    y_lo_: F64
    y_hi_: F64
    theta_: F64
    train_result_: TrainResult

    def __init__(self, *, hidden: int = 10, goal_mse: float = 1e-4, max_epochs: int = 1000,
                 val_fraction: float = 0.15, seed: int = 0, range_margin: float = 0.1,
                 constants: SensorConstants = DEFAULT_CONSTANTS,
                 r0_ohm: ArrayLike | None = None) -> None:
        super().__init__(constants=constants, r0_ohm=r0_ohm)
        if not (isinstance(hidden, int) and 1 <= hidden <= 1000):
            raise DecodeError(f"hidden must be an integer in [1, 1000], got {hidden!r}")
        if not (0.0 <= val_fraction < 1.0 and goal_mse >= 0.0 and max_epochs >= 0
                and range_margin >= 0.0):
            raise DecodeError("val_fraction in [0, 1), goal_mse >= 0, max_epochs >= 0 and "
                              "range_margin >= 0 are required")
        self.hidden, self.goal_mse, self.max_epochs = hidden, goal_mse, max_epochs
        self.val_fraction, self.seed, self.range_margin = val_fraction, seed, range_margin

    def _layout(self) -> Layout:
        n = T * int(self.pillars_)
        return Layout(n, self.hidden, n if self.pillars_ == 3 else T)

    def fit(self, resistance_ohm: ArrayLike, force_N: ArrayLike, *,
            progress: Progress | None = None) -> Self:
        r, _ = fold_resistance(resistance_ohm)
        force = fold_force(force_N, r.shape[0])
        pillars = r.shape[-1]
        x = r.reshape(r.shape[0], -1)
        codes = worst_reason(classify_resistance(r, self.constants))
        keep = np.all(codes == 0, axis=1)
        options = LMOptions(goal_mse=self.goal_mse, max_epochs=self.max_epochs)
        state, self.train_result_ = fit_mlp(
            x[keep], targets(force[keep], pillars), hidden=self.hidden, options=options,
            val_fraction=self.val_fraction, seed=self.seed, progress=progress)
        for key, value in state.items():
            setattr(self, key, value)
        self.pillars_ = pillars
        self._prepare()
        return self

    @property
    def train_result(self) -> TrainResult | None:
        """How the last fit ended (None after load)."""
        return getattr(self, "train_result_", None)

    def _prepare(self) -> None:
        state = {k: getattr(self, k) for k in ("x_lo_", "x_hi_", "y_lo_", "y_hi_", "theta_")}
        self._net = FoldedMLP(self._layout(), state)
        margin = self.range_margin * (self.x_hi_ - self.x_lo_)
        self._lo, self._hi = self.x_lo_ - margin, self.x_hi_ + margin
        self._mid = 0.5 * (self.x_lo_ + self.x_hi_)

    def _check_state(self) -> None:
        if self.pillars_ not in (1, 3) or isinstance(self.pillars_, bool):
            raise ModelFileError(f"state.pillars_: must be 1 or 3, got {self.pillars_!r}")
        layout = self._layout()
        for key in ("x_lo_", "x_hi_"):
            expect_array(getattr(self, key), key, (layout.n_in,))
        for key in ("y_lo_", "y_hi_"):
            expect_array(getattr(self, key), key, (layout.n_out,))
        expect_array(self.theta_, "theta_", (layout.n_params,))
        if np.any(self.x_lo_ > self.x_hi_) or np.any(self.y_lo_ > self.y_hi_):
            raise ModelFileError("state.x_lo_: a scaling range has min > max")
        self._prepare()

    def decode(self, resistance_ohm: ArrayLike) -> Decoded:
        self._require_fitted()
        r, lead = fold_resistance(resistance_ohm)
        if r.shape[-1] != self.pillars_:
            raise DecodeError(f"model was fitted on {self.pillars_}-pillar input, "
                              f"got {r.shape[-1]} pillars")
        x = r.reshape(r.shape[0], -1)
        ok = (x >= self._lo) & (x <= self._hi)
        if ok.all():
            force = to_force(self._net(x), self.pillars_)
            n = r.shape[0]
            return unfold(Decoded(force, np.ones((n, T), bool), np.zeros((n, T), np.uint8)), lead)
        reason = self._reasons(r, ok)
        x = np.where(np.repeat(reason != 0, self.pillars_, axis=1), self._mid, x)
        force = to_force(self._net(x), self.pillars_)
        force[reason != 0] = 0.0
        return unfold(Decoded(force, reason == 0, reason), lead)

    def _reasons(self, r: F64, ok: NDArray[np.bool_]) -> NDArray[np.uint8]:
        in_range = ok.reshape(r.shape).all(axis=-1)
        code = worst_reason(classify_resistance(r, self.constants))
        return np.where((code == 0) & ~in_range, np.uint8(Reason.OUT_OF_RANGE), code)
