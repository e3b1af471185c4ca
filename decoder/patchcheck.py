"""Domain checks that see the whole patch, calibrated on held-out rows of the training data.

Two checks, both on the physics reading of the patch (the exact inverse and the crosstalk
inverse fitted on the same data: forces that transfer between scenes) and both calibrated so
that on the scene a decoder was trained on they flag few samples:

- ``PatternCheck``: is this pattern of forces one the training set showed? The Mahalanobis
  distance of the patch's physics reading (9·P forces together) from the training rows,
  against a limit set by contiguous-block cross-validation: the training rows are cut into
  ``FOLDS`` blocks in their order, and each block is measured against a fit to the others.
  A block holds samples the fit never saw, as a new recording of the scene would: a
  training set of a few long episodes (five squeeze cycles of a grasp) is judged by episodes
  it did not contain, not by rows next to ones it did.
- ``DepartureCheck``: does the network depart from the physics reading as it did on rows
  it was not fitted on? Two statistics of the departure d = network - physics: the
  Mahalanobis distance of the patch's whole departure vector (the joint pattern: a network
  confused by a new scene departs on many taxels a little, together), and each taxel's
  largest departure relative to its force, over the components that carry load (the floored
  error the bar is measured in: a press of 0.3 N read 0.05 N off is 17 % off, even where a
  5 N press of the training scene may be 0.05 N off). Limits come from the network's
  validation rows.

Each limit is a high quantile of held-out values (``PATTERN_Q``, ``PATCH_Q``, ``TAXEL_Q``):
a fresh sample of the training distribution exceeds it with probability at most 1 - q
(the held-out values and the new one are exchangeable; the limit is the
ceil((m + 1)·q)-th smallest of m values, the split-conformal rank).

Whether the validation rows can calibrate the departure check is itself measured
(:func:`exchangeability`): the pattern distance of a held-out block, against that of rows
held out at random. On data whose rows are exchangeable the two agree (ratio at most 1.14
over the 105 drawn scene pairs of ``skin.benchmarks.pairs`` whose training scene is not a grasp, and
over the shipped scenes but `grasp`); a few long episodes make a held-out block far less
familiar than a random row (ratio 11 to 10^7 on the 15 drawn grasps, 30 on the shipped
`grasp`). Then the validation rows, random rows of the training episodes, would set the
departure limit far below what a new episode shows, and the decoder would refuse its own
scene; above ``EXCHANGEABLE_RATIO`` the departure check is not used and the pattern check
alone decides.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from decoder.box import F64, Box, Mask, whitening
from skin.constants import TAXELS_PER_PATCH
from skin.errors import ModelFileError

FOLDS = 4
PATTERN_Q = 0.99
PATCH_Q = 0.99
TAXEL_Q = 0.98
SLACK = 1.25
"""Every limit is this times its held-out quantile. A quantile of 150 validation rows is itself
a draw: a fresh sample passes the largest of m exchangeable values with probability m/(m + 1)
only on average over training sets, and one set in 25 lets through fewer than 96.5 % of its own
scene. Three checks add up. Over 120 drawn scene pairs of ``skin.benchmarks.pairs``, lm-mlp
flagged at most 3.7 % of its own scene with the slack (median 0.5 %); the same limits without
it, computed on the same networks, flagged up to 5.6 % (docs/decoders.md)."""
EXCHANGEABLE_RATIO = 2.0
"""Above this ratio of held-out-block to held-out-row pattern distances the training rows are
episodes, and the validation rows cannot calibrate the departure check."""


NO_LIMIT = float(np.finfo(np.float64).max)
"""The limit of a check with no held-out value to set it (model files hold finite numbers)."""
TINY = 1e-300


def conformal_limit(values: F64, q: float) -> float:
    """The ceil((m + 1)·q)-th smallest of m held-out values (the largest if that is past m):
    a new exchangeable value exceeds it with probability at most 1 - q (at most 1/(m + 1)
    for the largest). ``NO_LIMIT`` for no values; at least ``TINY``."""
    ordered = np.sort(np.asarray(values, dtype=np.float64).ravel())
    if ordered.size == 0:
        return NO_LIMIT
    rank = min(math.ceil((ordered.size + 1) * q), ordered.size)
    return max(float(ordered[rank - 1]), TINY)


@dataclass(frozen=True)
class Whitened:
    """Squared Mahalanobis distance |(x - mean) @ whiten|² of rows (n, k) or one row (k,)."""

    mean: F64
    whiten: F64

    @classmethod
    def fit(cls, x: F64) -> Whitened:
        mean, whiten = whitening(x)
        return cls(mean, whiten)

    def squared(self, x: F64) -> F64:
        z = (x - self.mean) @ self.whiten
        if z.ndim == 1:
            return np.asarray(np.dot(z, z))
        out: F64 = np.einsum("ij,ij->i", z, z)
        return out

    def state(self) -> dict[str, Any]:
        return {"mean": self.mean, "whiten": self.whiten}


def _blocks(n: int, folds: int, order: NDArray[np.intp] | None = None) -> list[NDArray[np.intp]]:
    rows = np.arange(n) if order is None else order
    return [b for b in np.array_split(rows, min(folds, n)) if b.size]


def held_out_distances(x: F64, blocks: list[NDArray[np.intp]]) -> F64:
    """Each block's squared pattern distance from a fit to the other rows."""
    out = np.empty(x.shape[0])
    for block in blocks:
        rest = np.ones(x.shape[0], dtype=bool)
        rest[block] = False
        out[block] = Whitened.fit(x[rest]).squared(x[block])
    return out


def exchangeability(x: F64, folds: int = FOLDS, seed: int = 0) -> tuple[F64, float]:
    """Held-out pattern distances of contiguous blocks, and their ``PATTERN_Q`` quantile over
    that of rows held out at random (1 for exchangeable rows; large for a few episodes)."""
    blocks = held_out_distances(x, _blocks(x.shape[0], folds))
    order = np.random.default_rng(seed).permutation(x.shape[0])
    shuffled = held_out_distances(x, _blocks(x.shape[0], folds, order))
    top = conformal_limit(shuffled, PATTERN_Q)
    return blocks, conformal_limit(blocks, PATTERN_Q) / top


def slack(limit: float) -> float:
    """``SLACK`` times a limit (``NO_LIMIT`` stays as it is)."""
    return min(SLACK * limit, NO_LIMIT)


def block_margin(x: F64, folds: int = FOLDS) -> float:
    """The margin (a fraction of the largest span, as ``Box`` takes it) that a box of the
    training rows needs so that held-out contiguous blocks fall inside it: each block against
    the box of the other rows, each row's largest excess, their ``PATTERN_Q`` quantile. Near
    0 for exchangeable rows; a new squeeze cycle of a grasp may reach past the few the
    training set held."""
    span = float(np.max(x.max(axis=0) - x.min(axis=0))) if x.shape[0] else 0.0
    if span <= 0:
        return 0.0
    excess = np.zeros(x.shape[0])
    for block in _blocks(x.shape[0], folds):
        rest = np.ones(x.shape[0], dtype=bool)
        rest[block] = False
        if not rest.any():
            continue
        lo, hi = x[rest].min(axis=0), x[rest].max(axis=0)
        excess[block] = np.maximum(lo - x[block], x[block] - hi).max(axis=1).clip(min=0.0)
    return conformal_limit(excess, PATTERN_Q) / span


def _expect(value: Any, field: str, shape: tuple[int, ...]) -> F64:
    if not isinstance(value, np.ndarray) or value.dtype != np.float64 or value.shape != shape:
        got = value.shape if isinstance(value, np.ndarray) else type(value).__name__
        raise ModelFileError(f"{field}: expected float64 array of shape {shape}, got {got}")
    if not np.all(np.isfinite(value)):
        raise ModelFileError(f"{field}: must be finite")
    return value


def _limit(state: dict[str, Any], key: str, field: str) -> float:
    value = state[key]
    if isinstance(value, bool) or not isinstance(value, float | int) or not value > 0 \
            or not math.isfinite(value):
        raise ModelFileError(f"{field}.{key}: must be a positive finite number, got {value!r}")
    return float(value)


def _keys(state: Any, keys: set[str], field: str) -> dict[str, Any]:
    if not isinstance(state, dict) or set(state) != keys:
        raise ModelFileError(f"{field}: expected a map with keys {sorted(keys)}")
    return state


@dataclass(frozen=True)
class PatternCheck:
    """The patch's physics reading (n, 9·P) against the training rows' pattern."""

    shape: Whitened
    limit: float

    @classmethod
    def fit(cls, physics: F64, held_out: F64) -> PatternCheck:
        """``held_out``: the training rows' held-out squared distances (block CV)."""
        return cls(Whitened.fit(physics), slack(conformal_limit(held_out, PATTERN_Q)))

    def inside(self, physics: F64) -> Mask:
        """(n, 9·P) -> (n,), (9·P,) -> (); NaN is outside."""
        inside: Mask = np.asarray(self.shape.squared(physics) <= self.limit)
        return inside

    def to_state(self) -> dict[str, Any]:
        return {**self.shape.state(), "limit": self.limit}

    @classmethod
    def from_state(cls, state: Any, field: str, size: int) -> PatternCheck:
        state = _keys(state, {"mean", "whiten", "limit"}, field)
        return cls(Whitened(_expect(state["mean"], f"{field}.mean", (size,)),
                            _expect(state["whiten"], f"{field}.whiten", (size, size))),
                   _limit(state, "limit", field))


def relative_departure(departure: F64, physics: F64, floor_N: float) -> F64:
    """Each taxel's largest |departure| / |physics| over its components carrying at least
    ``floor_N`` (0 where none does): (n, 9·P) -> (n, 9), (9·P,) -> (9,)."""
    size = np.abs(physics)
    rel = np.abs(departure) / np.maximum(size, floor_N)
    rel[size < floor_N] = 0.0
    rel[np.isnan(departure)] = np.inf
    per = rel.shape[-1] // TAXELS_PER_PATCH
    return np.asarray(rel.reshape(*rel.shape[:-1], TAXELS_PER_PATCH, per).max(axis=-1))


@dataclass(frozen=True)
class DepartureCheck:
    """The network's departure from the physics reading, the patch's as a whole and each
    loaded taxel's relative to its force."""

    shape: Whitened
    patch_limit: float
    taxel_limit: float
    floor_N: float

    @classmethod
    def fit(cls, fitted: F64, held_out: F64, held_out_physics: F64,
            floor_N: float) -> DepartureCheck:
        """``fitted``: departures on rows the network was fitted on (they set the shape);
        ``held_out``: on its validation rows, with their physics reading (they set the
        limits)."""
        shape = Whitened.fit(fitted)
        rel = relative_departure(held_out, held_out_physics, floor_N)
        loaded = relative_departure(np.ones_like(held_out), held_out_physics, floor_N) > 0
        return cls(shape, slack(conformal_limit(shape.squared(held_out), PATCH_Q)),
                   slack(conformal_limit(rel[loaded], TAXEL_Q)), floor_N)

    def inside(self, departure: F64, physics: F64) -> Mask:
        """(n, 9·P) -> (n, 9), (9·P,) -> (9,): the patch check on every taxel of a sample,
        the relative check per taxel; NaN is outside."""
        patch = np.asarray(self.shape.squared(departure) <= self.patch_limit)
        taxel = relative_departure(departure, physics, self.floor_N) <= self.taxel_limit
        inside: Mask = taxel & patch[..., None]
        return inside

    def all_inside(self, departure: F64, physics: F64) -> bool:
        """Whether every taxel of these rows is inside (the fast path's check: the same
        comparisons as :meth:`inside`, without building the mask; False for any NaN)."""
        if not bool(np.all(self.shape.squared(departure) <= self.patch_limit)):
            return False
        size = np.abs(physics)
        rel = np.abs(departure) / np.maximum(size, self.floor_N)
        return bool(np.all((rel <= self.taxel_limit) | (size < self.floor_N)))

    def to_state(self) -> dict[str, Any]:
        return {**self.shape.state(), "patch_limit": self.patch_limit,
                "taxel_limit": self.taxel_limit, "floor_N": self.floor_N}

    @classmethod
    def from_state(cls, state: Any, field: str, size: int) -> DepartureCheck:
        state = _keys(state, {"mean", "whiten", "patch_limit", "taxel_limit", "floor_N"}, field)
        return cls(Whitened(_expect(state["mean"], f"{field}.mean", (size,)),
                            _expect(state["whiten"], f"{field}.whiten", (size, size))),
                   _limit(state, "patch_limit", field), _limit(state, "taxel_limit", field),
                   _limit(state, "floor_N", field))


@dataclass(frozen=True)
class PatchChecks:
    """Both checks as fitted on a training set, and what the fit measured (for ``meta``)."""

    pattern: PatternCheck
    departure: DepartureCheck | None
    exchangeable_ratio: float
    input_margin: float = 0.0
    output_margin: float = 0.0

    def to_meta(self) -> dict[str, Any]:
        departure = self.departure
        used = departure is not None
        return {"input_margin": self.input_margin, "output_margin": self.output_margin,
                "pattern_limit": self.pattern.limit, "pattern_q": PATTERN_Q, "folds": FOLDS,
                "exchangeable_ratio": self.exchangeable_ratio,
                "exchangeable_ratio_limit": EXCHANGEABLE_RATIO,
                "departure_check": "validation rows" if used else
                "off: held-out blocks are far less familiar than held-out rows (the training "
                "set is a few long episodes); the pattern check alone decides",
                "patch_limit": None if departure is None else departure.patch_limit,
                "taxel_limit": None if departure is None else departure.taxel_limit,
                "patch_q": PATCH_Q, "taxel_q": TAXEL_Q}


def fit_patch_checks(departure: F64, physics: F64, val_rows: NDArray[np.intp],
                     floor_N: float) -> PatchChecks:
    """The checks of a network trained on rows whose physics reading is ``physics`` (n, 9·P)
    and whose departure from it is ``departure``; ``val_rows`` were held out of its fit (none:
    its fitted rows set the limits, a looser check)."""
    blocks, ratio = exchangeability(physics)
    pattern = PatternCheck.fit(physics, blocks)
    if ratio > EXCHANGEABLE_RATIO:
        return PatchChecks(pattern, None, ratio)
    fitted = np.ones(physics.shape[0], dtype=bool)
    fitted[val_rows] = False
    held = val_rows if val_rows.size else np.arange(physics.shape[0])
    return PatchChecks(pattern, DepartureCheck.fit(departure[fitted], departure[held],
                                                   physics[held], floor_N), ratio)


def fit_boxes(x: F64, y: F64, predicted: F64, margin: float,
              checks: PatchChecks) -> tuple[Box, Box, PatchChecks]:
    """The boxes of the readings ``x`` and of the forces (true ``y`` and the network's
    ``predicted``), each widened by ``margin`` or by what held-out blocks need, if more."""
    need_in, need_out = block_margin(x), block_margin(y)
    inputs = Box.fit(x, max(margin, need_in))
    outputs = Box.fit(np.concatenate((y, predicted)), max(margin, need_out))
    return inputs, outputs, dataclasses.replace(checks, input_margin=max(margin, need_in),
                                                output_margin=max(margin, need_out))
