"""A trained decoder's training domain, and whether a new sample lies inside it.

Four checks, each fitted on the training data and kept in the model file:

- ``Box``: per-feature ranges. Each feature may go beyond its training range by
  ``margin`` times the largest span among the box's features, so a feature that
  never moved in training (the shear of a press-only set, say) gets the same
  tolerance as the others instead of none.
- ``Ellipsoid``: the Mahalanobis distance of a whole sample from the training
  samples' mean under their covariance. The features are standardised and the
  covariance gets a ridge of ``decoder.box.RIDGE``, so a direction the training data never
  moved in (a load pattern it never saw) is far away. A sample is inside when its
  distance is at most ``DENSITY_FACTOR`` times the largest training distance.
- ``Band``: per-output bound on the size of a learned quantity (an MLP's
  departure from the physics reading): ``BAND_FACTOR`` times its largest
  training value, plus ``BAND_FLOOR`` times the outputs' span.
- ``TaxelBand``: the same quantity judged per taxel, its P components jointly (Fx,
  Fy, Fz of a 3-axis taxel): each taxel's values are whitened by their own mean and
  covariance in training, and a taxel is inside when its whitened length is at most
  ``TAXEL_BAND_FACTOR`` times the largest among *held-out* training rows (rows the
  learned quantity was not fitted on), all taxels pooled. A new taxel from the training
  distribution is beyond the largest of N exchangeable held-out values with probability
  at most 1/(N + 1) (N = 9 x the held-out rows); the factor makes that rarer still.
  Components that each stay inside their band can together make a departure that
  training never showed (a shear the physics does not see, with a smaller Fz).

Features are laid out taxel-major, so feature ``f`` of a (n, 9·k) array belongs
to taxel ``f // k``: :func:`per_taxel` turns a feature mask into a taxel mask.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from decoder.box import F64, Box, Mask, expect_array, whitening
from decoder.patchcheck import DepartureCheck, PatternCheck
from decoder.reasons import Reason
from skin.constants import TAXELS_PER_PATCH
from skin.errors import DecodeError, ModelFileError

DENSITY_FACTOR = 1.1
"""A sample is inside the ellipsoid up to 1.1x the farthest training sample's distance. A new
sample from the training distribution lies beyond the farthest of n training samples with
probability 1/(n + 1); the 10 % make that rarer still."""
BAND_FACTOR = 1.2
BAND_FLOOR = 0.001
"""A band is at least 0.1 % of its outputs' span wide, so a decoder that fitted its training
data exactly still tolerates rounding."""
TAXEL_BAND_FACTOR = 1.2
"""A taxel is inside its band up to 1.2x the largest whitened length among held-out rows."""


def check_margin(range_margin: float) -> float:
    """A decoder's ``range_margin`` parameter, checked."""
    if isinstance(range_margin, bool) or not (isinstance(range_margin, float | int)
                                               and 0.0 <= range_margin <= 10.0):
        raise DecodeError(f"range_margin must be in [0, 10], got {range_margin!r}")
    return float(range_margin)


def domain_reasons(reason: NDArray[np.uint8], outside: Mask) -> NDArray[np.uint8]:
    """EXTRAPOLATED, in place, where a taxel that decoded is ``outside`` its domain (n, 9)."""
    reason[outside & (reason == 0)] = Reason.EXTRAPOLATED
    return reason


def per_taxel(mask: Mask) -> Mask:
    """(n, 9·k) feature mask -> (n, 9) taxel mask: a taxel is marked if any of its features is."""
    per = mask.shape[1] // TAXELS_PER_PATCH
    return np.asarray(mask.reshape(mask.shape[0], TAXELS_PER_PATCH, per).any(axis=2))


@dataclass(frozen=True)
class Ellipsoid:
    """Inside when |(x - mean) @ whiten| <= limit; ``whiten`` (k, k) is upper triangular."""

    mean: F64
    whiten: F64
    limit: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "_limit2", self.limit * self.limit)

    @classmethod
    def fit(cls, x: F64) -> Ellipsoid:
        mean, whiten = whitening(x)
        distance = np.sqrt(np.sum(((x - mean) @ whiten) ** 2, axis=1))
        return cls(mean, whiten, DENSITY_FACTOR * float(distance.max()))

    def distance(self, x: F64) -> F64:
        """(n, k) -> (n,) or (k,) -> () Mahalanobis distances; NaN stays NaN."""
        return np.sqrt(self._squared(x))

    def _squared(self, x: F64) -> F64:
        z = (x - self.mean) @ self.whiten
        if z.ndim == 1:
            return np.asarray(np.dot(z, z))
        squared: F64 = np.einsum("ij,ij->i", z, z)
        return squared

    def inside(self, x: F64) -> Mask:
        """(n, k) -> (n,), or (k,) -> (); NaN is outside. ``x`` must be finite and of the
        training data's order of magnitude (the decoders check their box first)."""
        inside: Mask = np.asarray(self._squared(x) <= self._limit2)  # type: ignore[attr-defined]
        return inside

    def to_state(self) -> dict[str, Any]:
        return {"mean": self.mean, "whiten": self.whiten, "limit": self.limit}

    @classmethod
    def from_state(cls, state: Any, field: str, size: int) -> Ellipsoid:
        if not isinstance(state, dict) or set(state) != {"mean", "whiten", "limit"}:
            raise ModelFileError(f"{field}: expected a map with keys ['limit', 'mean', 'whiten']")
        mean = expect_array(state["mean"], f"{field}.mean", (size,))
        whiten = expect_array(state["whiten"], f"{field}.whiten", (size, size))
        limit = state["limit"]
        if isinstance(limit, bool) or not isinstance(limit, float | int) or not limit > 0:
            raise ModelFileError(f"{field}.limit: must be a positive number, got {limit!r}")
        return cls(mean, whiten, float(limit))


@dataclass(frozen=True)
class Band:
    """Per-output bound (k,) on the magnitude of a learned quantity."""

    bound: F64

    @classmethod
    def fit(cls, values: F64, span: F64) -> Band:
        """``values`` (n, k) seen in training; ``span`` (k,) the outputs' training span."""
        largest = np.abs(values).max(axis=0) if values.shape[0] else np.zeros(values.shape[1])
        return cls(BAND_FACTOR * largest + BAND_FLOOR * np.max(span))

    def inside(self, values: F64) -> Mask:
        inside: Mask = np.abs(values) <= self.bound
        return inside

    def all_inside(self, values: F64) -> bool:
        return bool(self.inside(values).all())

    def to_state(self) -> F64:
        return self.bound

    @classmethod
    def from_state(cls, state: Any, field: str, size: int) -> Band:
        bound = expect_array(state, field, (size,))
        if np.any(bound < 0):
            raise ModelFileError(f"{field}: must be >= 0")
        return cls(bound)


@dataclass(frozen=True)
class TaxelBand:
    """Per taxel, the whitened length of the P components of a learned quantity (n, 9·P).

    Taxel t is inside when |(v_t - mean_t) @ whiten_t| <= limit, with ``whiten`` (9, P, P)
    fitted per taxel and one ``limit`` for all taxels, from held-out rows. The blocks are
    applied as one block-diagonal (9·P, 9·P) product."""

    mean: F64
    whiten: F64
    limit: float

    def __post_init__(self) -> None:
        full = np.ascontiguousarray(scipy.linalg.block_diag(*self.whiten))
        pillars = self.whiten.shape[1]
        object.__setattr__(self, "_full", full)
        object.__setattr__(self, "_shift", self.mean @ full)
        # Sums each taxel's P squared components: (9·P,) @ (9·P, 9) -> (9,).
        object.__setattr__(self, "_sum", np.kron(np.eye(TAXELS_PER_PATCH), np.ones((pillars, 1))))
        object.__setattr__(self, "_limit2", self.limit * self.limit)

    @classmethod
    def fit(cls, values: F64, held_out: F64, pillars: int) -> TaxelBand:
        """``values`` (n, 9·P) to whiten by, ``held_out`` (m, 9·P) rows they were not fitted
        on that set the limit (``values`` themselves if m = 0)."""
        parts = [whitening(values[:, t * pillars:(t + 1) * pillars])
                 for t in range(TAXELS_PER_PATCH)]
        mean = np.concatenate([p[0] for p in parts])
        band = cls(mean, np.stack([p[1] for p in parts]), 1.0)
        reference = held_out if held_out.shape[0] else values
        largest = float(np.sqrt(band.squared(reference).max()))
        return cls(mean, band.whiten, TAXEL_BAND_FACTOR * max(largest, 1e-12))

    def squared(self, values: F64) -> F64:
        """(n, 9·P) -> (n, 9) or (9·P,) -> (9,) squared whitened lengths; a NaN makes its whole
        row NaN (the block-diagonal product mixes it into every taxel)."""
        product = np.dot if values.ndim == 1 else np.matmul  # np.dot: less overhead for a vector
        z = product(values, self._full)  # type: ignore[attr-defined]
        z -= self._shift  # type: ignore[attr-defined]
        z *= z
        squared: F64 = product(z, self._sum)  # type: ignore[attr-defined]
        return squared

    def inside(self, values: F64) -> Mask:
        """(n, 9·P) -> (n, 9), or (9·P,) -> (9,); a row with a NaN is outside everywhere."""
        inside: Mask = self.squared(values) <= self._limit2  # type: ignore[attr-defined]
        return inside

    def all_inside(self, values: F64) -> bool:
        """Whether every taxel is inside (False for any NaN; True for no rows)."""
        squared = self.squared(values)
        return not squared.size or bool(squared.max() <= self._limit2)  # type: ignore[attr-defined]

    def to_state(self) -> dict[str, Any]:
        return {"mean": self.mean, "whiten": self.whiten, "limit": self.limit}

    @classmethod
    def from_state(cls, state: Any, field: str, size: int) -> TaxelBand:
        if not isinstance(state, dict) or set(state) != {"mean", "whiten", "limit"}:
            raise ModelFileError(f"{field}: expected a map with keys ['limit', 'mean', 'whiten']")
        pillars = size // TAXELS_PER_PATCH
        mean = expect_array(state["mean"], f"{field}.mean", (size,))
        whiten = expect_array(state["whiten"], f"{field}.whiten",
                              (TAXELS_PER_PATCH, pillars, pillars))
        limit = state["limit"]
        if isinstance(limit, bool) or not isinstance(limit, float | int) or not limit > 0:
            raise ModelFileError(f"{field}.limit: must be a positive number, got {limit!r}")
        return cls(mean, whiten, float(limit))


OPTIONAL = ("density", "band", "taxel_band", "pattern", "departure")


@dataclass(frozen=True)
class Domain:
    """What a decoder saw in training: its inputs' and outputs' boxes, and optionally the
    inputs' ellipsoid and bands on a learned quantity, per output and per taxel (model files
    of version 3 and before), or the checks of the whole patch (:mod:`decoder.patchcheck`)."""

    inputs: Box
    outputs: Box
    density: Ellipsoid | None = None
    band: Band | None = None
    taxel_band: TaxelBand | None = None
    pattern: PatternCheck | None = None
    departure: DepartureCheck | None = None

    def to_state(self) -> dict[str, Any]:
        state: dict[str, Any] = {"inputs": self.inputs.to_state(),
                                 "outputs": self.outputs.to_state()}
        for key in OPTIONAL:
            part = getattr(self, key)
            if part is not None:
                state[key] = part.to_state()
        return state

    @classmethod
    def from_state(cls, state: Any, field: str, n_in: int, n_out: int) -> Domain:
        if not isinstance(state, dict) or not {"inputs", "outputs"} <= set(state) \
                <= {"inputs", "outputs", *OPTIONAL}:
            raise ModelFileError(f"{field}: expected a map with keys 'inputs', 'outputs' "
                                 f"and optionally {', '.join(repr(k) for k in OPTIONAL)}")
        density, band, taxel, pattern, departure = (state.get(k) for k in OPTIONAL)
        return cls(
            Box.from_state(state["inputs"], f"{field}.inputs", n_in),
            Box.from_state(state["outputs"], f"{field}.outputs", n_out),
            None if density is None else Ellipsoid.from_state(density, f"{field}.density", n_in),
            None if band is None else Band.from_state(band, f"{field}.band", n_out),
            None if taxel is None else TaxelBand.from_state(taxel, f"{field}.taxel_band", n_out),
            None if pattern is None
            else PatternCheck.from_state(pattern, f"{field}.pattern", n_out),
            None if departure is None
            else DepartureCheck.from_state(departure, f"{field}.departure", n_out),
        )
