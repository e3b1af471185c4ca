"""An LM-trained MLP regressor on plain feature arrays: the engine of lm-mlp and hybrid.

Inputs and outputs are scaled by mapminmax to [-1, 1]; the training goal is an
MSE on the scaled outputs. The data are split at random into training and
validation sets (85/15, like MATLAB's dividerand without its test share).
After training, the scalings are folded into the weights so prediction is two
matrix products and one tanh.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from decoder.lm import LMOptions, TrainResult, train_lm
from decoder.mlp import F64, Layout, mapminmax, minmax_range, nguyen_widrow
from decoder.protocol import BaseDecoder, Progress, expect_array
from skin.constants import TAXELS_PER_PATCH, SensorConstants
from skin.errors import DecodeError, ModelFileError


def split_indices(
    n: int, val_fraction: float, rng: np.random.Generator
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    order = rng.permutation(n)
    n_val = round(val_fraction * n) if n >= 8 else 0
    return order[n_val:], order[:n_val]


def fit_mlp(
    x: F64, y: F64, *, hidden: int, options: LMOptions, val_fraction: float, seed: int,
    progress: Progress | None = None, theta0: F64 | None = None,
) -> tuple[dict[str, F64], TrainResult]:
    """Train on raw (n, I) inputs and (n, O) targets; returns the state arrays and the result."""
    if x.shape[0] < 2:
        raise DecodeError(f"need at least 2 valid training samples, got {x.shape[0]}")
    x_lo, x_hi = minmax_range(x)
    y_lo, y_hi = minmax_range(y)
    xs, ys = mapminmax(x, x_lo, x_hi), mapminmax(y, y_lo, y_hi)
    rng = np.random.default_rng(seed)
    layout = Layout(x.shape[1], hidden, y.shape[1])
    theta = nguyen_widrow(layout, rng) if theta0 is None else theta0
    train, val = split_indices(x.shape[0], val_fraction, rng)
    theta, result = train_lm(layout, theta, (xs[train], ys[train]), (xs[val], ys[val]),
                             options, progress)
    state = {"x_lo_": x_lo, "x_hi_": x_hi, "y_lo_": y_lo, "y_hi_": y_hi, "theta_": theta}
    return state, result


def sample_rows(a: F64) -> F64:
    """(n, ...) -> one feature row per sample (n, k); one sample -> a vector (k,), so the
    network and the range checks run as vector operations, without broadcasting."""
    if a.shape[0] == 1:
        return a.reshape(-1)
    return a.reshape(a.shape[0], math.prod(a.shape[1:]))


class FoldedMLP:
    """Prediction in raw units: scalings folded into the first and last layers."""

    def __init__(self, layout: Layout, state: dict[str, F64]) -> None:
        A1, A2 = layout.unpack(state["theta_"])
        span_x = state["x_hi_"] - state["x_lo_"]
        gx = np.where(span_x > 0, 2.0 / np.where(span_x > 0, span_x, 1.0), 1.0)
        W1 = A1[:, :-1] * gx
        self.W1T = np.ascontiguousarray(W1.T)
        self.b1 = A1[:, -1] - W1 @ state["x_lo_"] - A1[:, :-1].sum(axis=1)
        span_y = state["y_hi_"] - state["y_lo_"]
        gy = np.where(span_y > 0, span_y / 2.0, 1.0)
        self.W2T = np.ascontiguousarray((A2[:, :-1] * gy[:, None]).T)
        self.b2 = (A2[:, -1] + 1.0) * gy + state["y_lo_"]

    def __call__(self, x: F64) -> F64:
        """Outputs (n, O) for inputs (n, I), or (O,) for one sample (I,)."""
        product = np.dot if x.ndim == 1 else np.matmul  # np.dot: less overhead for a vector
        h = product(x, self.W1T)
        h += self.b1
        np.tanh(h, out=h)
        y: F64 = product(h, self.W2T)
        y += self.b2
        return y


_SCALED_STATE = ("x_lo_", "x_hi_", "y_lo_", "y_hi_", "theta_")


class MLPDecoderBase(BaseDecoder):
    """What lm-mlp and hybrid share: options, the scaled-MLP state and its checks."""

    _state = ("pillars_", *_SCALED_STATE)

    pillars_: int
    x_lo_: F64
    x_hi_: F64
    y_lo_: F64
    y_hi_: F64
    theta_: F64
    train_result_: TrainResult

    def __init__(self, *, constants: SensorConstants, r0_ohm: ArrayLike | None, hidden: int,
                 goal_mse: float, max_epochs: int, val_fraction: float, seed: int) -> None:
        super().__init__(constants=constants, r0_ohm=r0_ohm)
        if not (isinstance(hidden, int) and 1 <= hidden <= 1000):
            raise DecodeError(f"hidden must be an integer in [1, 1000], got {hidden!r}")
        if not (0.0 <= val_fraction < 1.0 and goal_mse >= 0.0 and max_epochs >= 0):
            raise DecodeError("val_fraction in [0, 1), goal_mse >= 0, max_epochs >= 0 required")
        self.hidden, self.goal_mse, self.max_epochs = hidden, goal_mse, max_epochs
        self.val_fraction, self.seed = val_fraction, seed

    def _layout(self) -> Layout:
        n = TAXELS_PER_PATCH * int(self.pillars_)
        return Layout(n, self.hidden, n)

    def _fit_scaled(self, x: F64, y: F64, pillars: int, progress: Progress | None) -> None:
        options = LMOptions(goal_mse=self.goal_mse, max_epochs=self.max_epochs)
        state, self.train_result_ = fit_mlp(x, y, hidden=self.hidden, options=options,
                                            val_fraction=self.val_fraction, seed=self.seed,
                                            progress=progress)
        for key, value in state.items():
            setattr(self, key, value)
        self.pillars_ = pillars
        self._prepare()

    @property
    def train_result(self) -> TrainResult | None:
        """How the last fit ended (None after load)."""
        return getattr(self, "train_result_", None)

    def _prepare(self) -> None:
        state = {k: getattr(self, k) for k in _SCALED_STATE}
        self._net = FoldedMLP(self._layout(), state)

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
