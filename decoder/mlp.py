"""The paper's network: mapminmax scaling, one tanh hidden layer, linear output.

Parameters live in one flat vector theta = [A1.ravel(), A2.ravel()] with
A1 = [W1 | b1] of shape (H, I+1) and A2 = [W2 | b2] of shape (O, H+1).
The Gauss-Newton matrix JᵀJ is assembled from the Jacobian's structure
instead of the (samples·O × params) Jacobian itself:

* output block: every output row t sees the same hidden features h̃, so it is
  I_O ⊗ (H̃ᵀH̃);
* hidden block: with P[n,(j,i)] = (1 - h_nj²)·x̃_ni and C = W2ᵀW2 it is
  (C expanded to (j,i) indices) ⊙ PᵀP;
* cross block: W2[t,j]·(PᵀH̃)[(j,i),k].

``jacobian`` builds the dense J (used to check the structure and by the SciPy
reference); the trainer never does.

Errors may be weighted per output, r = w ⊙ e: trainlm measures its goal on the
un-normalised targets, so with mapminmax outputs each output's error is its
scaled error times that output's half-span (w = span/2). The weighted problem
is the same structure with W2 replaced by diag(w²)·W2 in the hidden-output
coupling and I_O by diag(w²).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Layout:
    """Sizes of the network: inputs, hidden nodes, outputs."""

    n_in: int
    n_hidden: int
    n_out: int

    @property
    def n_params(self) -> int:
        return self.n_hidden * (self.n_in + 1) + self.n_out * (self.n_hidden + 1)

    def unpack(self, theta: F64) -> tuple[F64, F64]:
        split = self.n_hidden * (self.n_in + 1)
        A1 = theta[:split].reshape(self.n_hidden, self.n_in + 1)
        A2 = theta[split:].reshape(self.n_out, self.n_hidden + 1)
        return A1, A2


def minmax_range(x: F64) -> tuple[F64, F64]:
    """Per-column (min, max) of training data for mapminmax."""
    return x.min(axis=0), x.max(axis=0)


def mapminmax_gain(lo: F64, hi: F64) -> F64:
    span = hi - lo
    return np.where(span > 0, 2.0 / np.where(span > 0, span, 1.0), 1.0)


def mapminmax(x: F64, lo: F64, hi: F64) -> F64:
    """Map each column from [lo, hi] to [-1, 1] (MATLAB mapminmax; constant columns gain 1)."""
    return (x - lo) * mapminmax_gain(lo, hi) - 1.0


def mapminmax_reverse(y: F64, lo: F64, hi: F64) -> F64:
    return (y + 1.0) / mapminmax_gain(lo, hi) + lo


def nguyen_widrow(layout: Layout, rng: np.random.Generator) -> F64:
    """MATLAB initnw for the tanh layer (inputs in [-1, 1]); rands for the linear layer."""
    H, I, O = layout.n_hidden, layout.n_in, layout.n_out  # noqa: E741 (paper notation)
    magnitude = 0.7 * H ** (1.0 / I)
    w = rng.uniform(-1.0, 1.0, (H, I))
    w *= magnitude / np.linalg.norm(w, axis=1, keepdims=True)
    b = magnitude * np.linspace(-1.0, 1.0, H) * np.sign(w[:, 0]) if H > 1 else np.zeros(1)
    A1 = np.column_stack((w, b))
    A2 = rng.uniform(-1.0, 1.0, (O, H + 1)) / math.sqrt(H + 1)
    return np.concatenate((A1.ravel(), A2.ravel()))


def _augment(x: F64) -> F64:
    return np.column_stack((x, np.ones(x.shape[0])))


@dataclass(frozen=True)
class Forward:
    """One forward pass: inputs with bias column, hidden activations with bias column, outputs."""

    x1: F64
    h1: F64
    y: F64


def forward(layout: Layout, theta: F64, x: F64) -> Forward:
    """Scaled inputs (n, I) -> scaled outputs (n, O)."""
    A1, A2 = layout.unpack(theta)
    x1 = _augment(x)
    h1 = np.empty((x.shape[0], layout.n_hidden + 1))
    np.matmul(x1, A1.T, out=h1[:, :-1])
    np.tanh(h1[:, :-1], out=h1[:, :-1])
    h1[:, -1] = 1.0
    return Forward(x1=x1, h1=h1, y=h1 @ A2.T)


def predict(layout: Layout, theta: F64, x: F64) -> F64:
    """Scaled outputs only, without keeping the intermediate arrays."""
    A1, A2 = layout.unpack(theta)
    h = np.tanh(x @ A1[:, :-1].T + A1[:, -1])
    out: F64 = h @ A2[:, :-1].T + A2[:, -1]
    return out


def normal_equations(
    layout: Layout, theta: F64, fw: Forward, e: F64, weight: F64 | None = None
) -> tuple[F64, F64]:
    """JᵀJ (params × params) and Jᵀr for residuals r = weight ⊙ (y - target), e = y - target
    of shape (n, O), ``weight`` (O,) or None for ones; J is the Jacobian of r."""
    H, I, O = layout.n_hidden, layout.n_in + 1, layout.n_out  # noqa: E741
    _, A2 = layout.unpack(theta)
    W2 = A2[:, :H]
    w2 = None if weight is None else weight * weight
    W2w = W2 if w2 is None else W2 * w2[:, None]
    d = 1.0 - fw.h1[:, :H] ** 2
    P = (d[:, :, None] * fw.x1[:, None, :]).reshape(-1, H * I)
    nh = H * I
    jtj = np.empty((layout.n_params, layout.n_params))
    C = np.repeat(np.repeat(W2.T @ W2w, I, axis=0), I, axis=1)
    jtj[:nh, :nh] = (P.T @ P) * C
    Q = (P.T @ fw.h1).reshape(H, I, 1, H + 1)
    cross = (W2w.T[:, None, :, None] * Q).reshape(nh, O * (H + 1))
    jtj[:nh, nh:] = cross
    jtj[nh:, :nh] = cross.T
    jtj[nh:, nh:] = np.kron(np.eye(O) if w2 is None else np.diag(w2), fw.h1.T @ fw.h1)
    ew = e if w2 is None else e * w2
    g_hidden = ((ew @ W2) * d).T @ fw.x1
    g_out = ew.T @ fw.h1
    return jtj, np.concatenate((g_hidden.ravel(), g_out.ravel()))


def jacobian(layout: Layout, theta: F64, x: F64, weight: F64 | None = None) -> F64:
    """Dense ∂r/∂theta of shape (n·O, params), rows ordered (sample, output), for
    r = weight ⊙ y (weight (O,), None for ones)."""
    H, I, O = layout.n_hidden, layout.n_in + 1, layout.n_out  # noqa: E741
    _, A2 = layout.unpack(theta)
    fw = forward(layout, theta, x)
    n = x.shape[0]
    d = 1.0 - fw.h1[:, :H] ** 2
    J = np.zeros((n, O, layout.n_params))
    hidden = A2[None, :, :H, None] * (d[:, None, :, None] * fw.x1[:, None, None, :])
    J[:, :, : H * I] = hidden.reshape(n, O, H * I)
    for t in range(O):
        start = H * I + t * (H + 1)
        J[:, t, start : start + H + 1] = fw.h1
    if weight is not None:
        J *= weight[None, :, None]
    return J.reshape(n * O, layout.n_params)
