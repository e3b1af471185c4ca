"""An LM-trained MLP regressor on plain feature arrays: the engine of lm-mlp and hybrid.

Inputs and outputs are scaled by mapminmax to [-1, 1]; the training goal is an
MSE on the scaled outputs. The data are split at random into training and
validation sets (85/15, like MATLAB's dividerand without its test share).
After training, the scalings are folded into the weights so prediction is two
matrix products and one tanh.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from decoder.lm import LMOptions, TrainResult, train_lm
from decoder.mlp import F64, Layout, mapminmax, minmax_range, nguyen_widrow
from decoder.protocol import Progress
from skin.errors import DecodeError


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
        h = x @ self.W1T
        h += self.b1
        np.tanh(h, out=h)
        y: F64 = h @ self.W2T
        y += self.b2
        return y
