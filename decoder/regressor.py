"""An LM-trained MLP regressor on plain feature arrays: the engine of lm-mlp and hybrid.

Inputs and outputs are scaled by mapminmax to [-1, 1]. The goal MSE is measured
on the targets in newtons by default (``goal_units="N"``), as MATLAB's default
performance function measures it on un-normalised targets; ``"scaled"``
measures it on the scaled outputs instead (a 4x-6x looser goal for forces
spanning 4-5 N). The data are split at random into training and validation
sets (85/15, like MATLAB's dividerand without its test share). After training,
the scalings are folded into the weights so prediction is two matrix products
and one tanh.

``hidden="auto"`` chooses the hidden layer by the paper's method
(:mod:`decoder.hidden`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from decoder.box import expect_array
from decoder.hidden import START, HiddenChoice, choose_hidden, eq21_candidates
from decoder.lm import LMOptions, TrainResult, train_lm
from decoder.mlp import F64, Layout, mapminmax, mapminmax_gain, minmax_range, nguyen_widrow
from decoder.protocol import BaseDecoder, Progress
from skin.constants import TAXELS_PER_PATCH, SensorConstants
from skin.errors import DecodeError, ModelFileError
from skin.inputs.budget import require_memory

GOAL_UNITS = ("N", "scaled")
"""Where the goal MSE is measured: on the targets in their own units (newtons; MATLAB's
default performance function on un-normalised targets), or on the mapminmax-scaled outputs."""


def split_indices(
    n: int, val_fraction: float, rng: np.random.Generator
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    order = rng.permutation(n)
    n_val = round(val_fraction * n) if n >= 8 else 0
    return order[n_val:], order[:n_val]


@dataclass(frozen=True)
class Problem:
    """Scaled training and validation data, the scalings, and the error weight per output."""

    val_rows: NDArray[np.intp]
    x_lo: F64
    x_hi: F64
    y_lo: F64
    y_hi: F64
    train: tuple[F64, F64]
    val: tuple[F64, F64]
    weight: F64 | None

    def state(self, theta: F64) -> dict[str, F64]:
        return {"x_lo_": self.x_lo, "x_hi_": self.x_hi, "y_lo_": self.y_lo,
                "y_hi_": self.y_hi, "theta_": theta}


def make_problem(x: F64, y: F64, *, val_fraction: float, rng: np.random.Generator,
                 goal_units: str) -> Problem:
    """Scale raw (n, I) inputs and (n, O) targets and split them."""
    if x.shape[0] < 2:
        raise DecodeError(f"need at least 2 valid training samples, got {x.shape[0]}")
    x_lo, x_hi = minmax_range(x)
    y_lo, y_hi = minmax_range(y)
    xs, ys = mapminmax(x, x_lo, x_hi), mapminmax(y, y_lo, y_hi)
    train, val = split_indices(x.shape[0], val_fraction, rng)
    weight = 1.0 / mapminmax_gain(y_lo, y_hi) if goal_units == "N" else None
    return Problem(val, x_lo, x_hi, y_lo, y_hi, (xs[train], ys[train]), (xs[val], ys[val]),
                   weight)


@dataclass(frozen=True)
class MLPFit:
    """A trained network: its state arrays (``theta_`` of the chosen size), how training ended,
    how ``hidden="auto"`` chose (None for a fixed size), and which rows were validation."""

    state: dict[str, F64]
    result: TrainResult
    choice: HiddenChoice | None
    val_rows: NDArray[np.intp]


def lm_bytes(layout: Layout, samples: int) -> int:
    """Memory one Levenberg-Marquardt epoch needs: JᵀJ and its temporaries (about five
    params x params matrices) and the hidden layer's Jacobian rows (twice)."""
    hidden_inputs = layout.n_hidden * (layout.n_in + 1)
    return 8 * (5 * layout.n_params ** 2 + 2 * samples * hidden_inputs)


def fit_mlp(
    x: F64, y: F64, *, hidden: int | str, options: LMOptions, val_fraction: float, seed: int,
    progress: Progress | None = None, goal_units: str = "N",
) -> MLPFit:
    """Train on raw (n, I) inputs and (n, O) targets."""
    rng = np.random.default_rng(seed)
    if hidden == "auto":
        width = max(START, eq21_candidates(x.shape[1], y.shape[1])[-1])
    else:
        width = int(hidden)
    layout = Layout(x.shape[1], width, y.shape[1])
    require_memory(lm_bytes(layout, x.shape[0]), f"Levenberg-Marquardt training of "
                   f"{width} hidden nodes ({layout.n_params} weights) on {x.shape[0]} samples",
                   "hidden")
    theta = nguyen_widrow(layout, rng)
    problem = make_problem(x, y, val_fraction=val_fraction, rng=rng, goal_units=goal_units)

    def train(net: Layout, start: F64) -> tuple[F64, TrainResult]:
        return train_lm(net, start, problem.train, problem.val, options, progress,
                        problem.weight)

    if hidden != "auto":
        theta, result = train(layout, theta)
        return MLPFit(problem.state(theta), result, None, problem.val_rows)
    layout, theta, result, choice = choose_hidden(layout, theta, train, problem.train[0],
                                                  problem.weight, options)
    return MLPFit(problem.state(theta), result, choice, problem.val_rows)


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


def check_hidden(hidden: Any) -> int | str:
    if hidden == "auto" or (isinstance(hidden, int) and not isinstance(hidden, bool)
                            and 1 <= hidden <= 1000):
        return hidden  # type: ignore[no-any-return]
    raise DecodeError(f"hidden must be an integer in [1, 1000] or 'auto', got {hidden!r}")


class MLPDecoderBase(BaseDecoder):
    """What lm-mlp and hybrid share: options, the scaled-MLP state and its checks."""

    _state: ClassVar[tuple[str, ...]] = ("pillars_", "hidden_", *_SCALED_STATE)

    pillars_: int
    hidden_: int
    x_lo_: F64
    x_hi_: F64
    y_lo_: F64
    y_hi_: F64
    theta_: F64
    train_result_: TrainResult
    hidden_choice_: HiddenChoice | None

    def __init__(self, *, constants: SensorConstants, r0_ohm: ArrayLike | None,
                 hidden: int | str, goal_mse: float, goal_units: str, max_epochs: int,
                 val_fraction: float, seed: int) -> None:
        super().__init__(constants=constants, r0_ohm=r0_ohm)
        self.hidden = check_hidden(hidden)
        if not (0.0 <= val_fraction < 1.0 and goal_mse >= 0.0 and max_epochs >= 0):
            raise DecodeError("val_fraction in [0, 1), goal_mse >= 0, max_epochs >= 0 required")
        if goal_units not in GOAL_UNITS:
            raise DecodeError(f"goal_units must be one of {', '.join(GOAL_UNITS)}, "
                              f"got {goal_units!r}")
        self.goal_mse, self.goal_units, self.max_epochs = goal_mse, goal_units, max_epochs
        self.val_fraction, self.seed = val_fraction, seed

    @classmethod
    def _upgrade(cls, params: dict[str, Any], state: dict[str, Any], version: int) -> None:
        params.setdefault("goal_units", "scaled")  # version 1 measured the goal on scaled outputs
        if "hidden_" not in state and isinstance(params.get("hidden"), int):
            state["hidden_"] = params["hidden"]

    def _layout(self) -> Layout:
        n = TAXELS_PER_PATCH * int(self.pillars_)
        return Layout(n, int(self.hidden_), n)

    def _fit_scaled(self, x: F64, y: F64, pillars: int,
                    progress: Progress | None) -> NDArray[np.intp]:
        """Train on raw rows; returns the validation rows."""
        options = LMOptions(goal_mse=self.goal_mse, max_epochs=self.max_epochs)
        fit = fit_mlp(x, y, hidden=self.hidden, options=options, val_fraction=self.val_fraction,
                      seed=self.seed, progress=progress, goal_units=self.goal_units)
        self.train_result_, self.hidden_choice_ = fit.result, fit.choice
        for key, value in fit.state.items():
            setattr(self, key, value)
        self.pillars_ = pillars
        self.hidden_ = (self.theta_.size - y.shape[1]) // (x.shape[1] + 1 + y.shape[1])
        self._prepare()
        return fit.val_rows

    @property
    def train_result(self) -> TrainResult | None:
        """How the last fit ended (None after load; the file's ``meta`` keeps it)."""
        return getattr(self, "train_result_", None)

    @property
    def hidden_choice(self) -> HiddenChoice | None:
        """How ``hidden="auto"`` chose, after fit (None otherwise)."""
        return getattr(self, "hidden_choice_", None)

    def meta(self) -> dict[str, Any]:
        result = self.train_result
        if result is None:
            return super().meta()
        meta: dict[str, Any] = {"training": {
            "goal_mse": float(self.goal_mse), "goal_units": self.goal_units,
            "message": result.message, "epochs": result.nit, "best_epoch": result.best_epoch,
            "train_mse": result.mse, "val_mse": None if math.isnan(result.val_mse)
            else result.val_mse, "seconds": result.elapsed_s}}
        if self.hidden_choice is not None:
            meta["hidden"] = self.hidden_choice.to_meta()
        return meta

    def _prepare(self) -> None:
        state = {k: getattr(self, k) for k in _SCALED_STATE}
        self._net = FoldedMLP(self._layout(), state)

    def _check_state(self) -> None:
        if self.pillars_ not in (1, 3) or isinstance(self.pillars_, bool):
            raise ModelFileError(f"state.pillars_: must be 1 or 3, got {self.pillars_!r}")
        if isinstance(self.hidden_, bool) or not isinstance(self.hidden_, int) \
                or not 1 <= self.hidden_ <= 1000:
            raise ModelFileError(f"state.hidden_: must be an integer in [1, 1000], "
                                 f"got {self.hidden_!r}")
        if self.hidden != "auto" and self.hidden != self.hidden_:
            raise ModelFileError(f"state.hidden_: {self.hidden_} but params.hidden is "
                                 f"{self.hidden}")
        layout = self._layout()
        for key in ("x_lo_", "x_hi_"):
            expect_array(getattr(self, key), f"state.{key}", (layout.n_in,))
        for key in ("y_lo_", "y_hi_"):
            expect_array(getattr(self, key), f"state.{key}", (layout.n_out,))
        expect_array(self.theta_, "state.theta_", (layout.n_params,))
        if np.any(self.x_lo_ > self.x_hi_) or np.any(self.y_lo_ > self.y_hi_):
            raise ModelFileError("state.x_lo_: a scaling range has min > max")
        self._prepare()
