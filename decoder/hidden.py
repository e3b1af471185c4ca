"""Choosing the hidden layer the paper's way: Eq. 21's candidates, then pruning from a wide layer.

The paper (section 3.3): "(21) is used to compute the hidden nodes number. After that,
we also try to set enough hidden nodes firstly, such as 20, and then during the
iterative training process, the invalid hidden nodes will be deleted. That process is
repeated, until the number of hidden nodes no longer changed or the target error is
gained." Here:

1. **Candidates** from Eq. 21, h = √(i + d) + a with a = 1..10, rounded: 5..14 for the
   paper's 9 inputs and 9 outputs, 8..17 in 3-axis mode (27 and 27).
2. **Start wide**: train max(20, largest candidate) hidden nodes.
3. **Delete nodes that carry nothing.** A node's saliency is how much the outputs (in the
   goal's units) move when its activation is replaced by its mean: the norm of its
   outgoing weights times the spread of its activation over the training data. Nodes
   below 1e-3 of the largest go together; otherwise the least salient one goes. Its mean
   contribution moves into the output biases, and the smaller network is retrained from
   there (warm start).
4. **Keep a deletion by validation error**: when the retrained network's validation MSE
   is at most (1 + ``tolerance``) times the larger of the goal and the best validation MSE
   so far. The first deletion refused inside the candidates' range ends the search ("the
   number of hidden nodes no longer changed"); above the range, deletions continue
   regardless, and the count never goes below the smallest candidate.

Every network trained is a step of the validation curve kept in the model file.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from decoder.lm import LMOptions, TrainResult
from decoder.mlp import F64, Layout, forward

START = 20
DEAD = 1e-3
TOLERANCE = 0.25

Trainer = Callable[[Layout, F64], tuple[F64, TrainResult]]
"""Trains a network of this layout from these weights on the fixed problem."""


def eq21_candidates(n_in: int, n_out: int) -> tuple[int, ...]:
    """h = √(i + d) + a, a = 1..10, rounded to whole nodes (Eq. 21)."""
    base = math.sqrt(n_in + n_out)
    return tuple(sorted({round(base + a) for a in range(1, 11)}))


@dataclass(frozen=True)
class PruneStep:
    """One network of the search: its size, how it trained, and whether it was kept."""

    hidden: int
    train_mse: float
    val_mse: float
    epochs: int
    kept: bool


@dataclass(frozen=True)
class HiddenChoice:
    """How ``--hidden auto`` chose: the candidates, the start, every step, and why it ended."""

    hidden: int
    candidates: tuple[int, ...]
    start: int
    steps: tuple[PruneStep, ...]
    stopped: str

    def to_meta(self) -> dict[str, Any]:
        """The model file's ``meta.hidden`` (arrays, so the file stays msgpack maps)."""
        return {
            "method": "paper Eq. 21 candidates, then pruning from a wide layer",
            "chosen": self.hidden,
            "candidates": np.array(self.candidates, dtype=np.int64),
            "start": self.start,
            "stopped": self.stopped,
            "curve": {
                "hidden": np.array([s.hidden for s in self.steps], dtype=np.int64),
                "train_mse": np.array([s.train_mse for s in self.steps]),
                "val_mse": np.array([s.val_mse for s in self.steps]),
                "epochs": np.array([s.epochs for s in self.steps], dtype=np.int64),
                "kept": np.array([s.kept for s in self.steps], dtype=bool),
            },
        }

    def describe(self) -> list[str]:
        """Lines for a terminal: the rule, the curve, the outcome."""
        lo, hi = self.candidates[0], self.candidates[-1]
        lines = [f"hidden auto: Eq. 21 candidates {lo}..{hi}; trained {self.start} nodes, "
                 "then deleted the least salient node and retrained while validation "
                 f"MSE stayed within {100 * TOLERANCE:.0f} % of the best (or of the goal)"]
        for s in self.steps:
            mark = "kept" if s.kept else "refused"
            lines.append(f"  {s.hidden:3d} nodes  train MSE {s.train_mse:.3e}  validation MSE "
                         f"{s.val_mse:.3e}  {s.epochs:4d} epochs  {mark}")
        lines.append(f"chose {self.hidden} hidden nodes: {self.stopped}")
        return lines


def saliency(layout: Layout, theta: F64, x: F64, weight: F64 | None) -> F64:
    """(H,) RMS change of the weighted outputs if each node's activation were its mean."""
    fw = forward(layout, theta, x)
    _, A2 = layout.unpack(theta)
    w2 = A2[:, : layout.n_hidden]
    if weight is not None:
        w2 = w2 * weight[:, None]
    spread = fw.h1[:, : layout.n_hidden].std(axis=0)
    out: F64 = np.linalg.norm(w2, axis=0) * spread
    return out


def remove_nodes(layout: Layout, theta: F64, nodes: list[int], x: F64) -> tuple[Layout, F64]:
    """The network without ``nodes``; their mean contribution moves into the output biases."""
    A1, A2 = layout.unpack(theta)
    mean = forward(layout, theta, x).h1[:, : layout.n_hidden].mean(axis=0)
    keep = np.setdiff1d(np.arange(layout.n_hidden), nodes)
    b2 = A2[:, -1] + A2[:, nodes] @ mean[nodes]
    A2_new = np.column_stack((A2[:, keep], b2))
    smaller = Layout(layout.n_in, keep.size, layout.n_out)
    return smaller, np.concatenate((A1[keep].ravel(), A2_new.ravel()))


def _step(layout: Layout, result: TrainResult, kept: bool) -> PruneStep:
    return PruneStep(layout.n_hidden, result.mse, result.val_mse, result.nit, kept)


def choose_hidden(
    layout: Layout, theta: F64, train: Trainer, x: F64, weight: F64 | None,
    options: LMOptions, tolerance: float = TOLERANCE,
) -> tuple[Layout, F64, TrainResult, HiddenChoice]:
    """Prune the wide network ``layout``/``theta`` (its size is the start) on scaled training
    inputs ``x``; returns the chosen network, its training result and how it was chosen."""
    candidates = eq21_candidates(layout.n_in, layout.n_out)
    lo, hi = candidates[0], candidates[-1]
    start = layout.n_hidden
    theta, result = train(layout, theta)
    steps = [_step(layout, result, True)]
    best_val = _val(result)
    stopped = f"reached the smallest candidate, {lo}"
    while layout.n_hidden > lo:
        s = saliency(layout, theta, x, weight)
        dead = [int(j) for j in np.flatnonzero(s < DEAD * s.max())]
        nodes = dead[: layout.n_hidden - lo] if dead else [int(np.argmin(s))]
        smaller, trial = remove_nodes(layout, theta, nodes, x)
        trial, trial_result = train(smaller, trial)
        allowed = (1.0 + tolerance) * max(options.goal_mse, best_val)
        kept = bool(_val(trial_result) <= allowed) or layout.n_hidden > hi
        steps.append(_step(smaller, trial_result, kept))
        if not kept:
            stopped = (f"deleting a node from {layout.n_hidden} raised the validation MSE to "
                       f"{trial_result.val_mse:.3e}, above {allowed:.3e}")
            break
        layout, theta, result = smaller, trial, trial_result
        best_val = min(best_val, _val(result))
    choice = HiddenChoice(layout.n_hidden, candidates, start, tuple(steps), stopped)
    return layout, theta, result, choice


def _val(result: TrainResult) -> float:
    """Validation MSE, or the training MSE when there is no validation set."""
    return result.mse if math.isnan(result.val_mse) else result.val_mse
