"""A patch's contact from its taxel forces: net force, torque, centre of pressure, slip.

Pure, vectorised numpy (float64) over ``n`` samples of one or many patches. The host
summarises every published sample with it and the simulator's truth uses it on the true
loads, so both measure the same thing.

Geometry. Taxel k sits at column k % 3, row k // 3 of the patch's grid, centre
((k % 3 - 1)·pitch, (k // 3 - 1)·pitch) in the *patch frame* (x right, y up seen from
above, z out of the skin: Fz > 0 presses in; :func:`sim.contact.taxel_xy` places them
alike). The config places the patch on the skin at ``position_m`` turned by
``orientation_deg`` about z: a point p of the patch frame is ``position + R(θ)·p`` in the
*placed frame*.

What counts. Only valid taxels that are *in contact* (normal force above
``taxel_contact_N``) carry the contact: a taxel without normal force carries no friction,
so its shear reading, like its normal one, is read noise. Over those taxels:

- net force F = Σ F_i; torque about the patch centre, on the skin's surface,
  τ = Σ r_i × F_i with r_i = (x_i, y_i, 0), so τx = Σ y_i·Fz_i, τy = −Σ x_i·Fz_i,
  τz = Σ (x_i·Fy_i − y_i·Fx_i);
- centre of pressure (Σ x_i·Fz_i, Σ y_i·Fz_i) / Σ Fz_i, defined only when a taxel is in
  contact (then Σ Fz_i > 0, so it is finite and inside the taxels' hull); otherwise 0
  with ``cop_defined`` False: no NaN, whatever the input;
- slip: the friction cone. The patch's tangential ratio |(Fx, Fy)| / Fz against the
  configured friction coefficient μ: at or beyond μ the contact slips (or is about to),
  within ``near_slip_margin`` of it (ratio ≥ (1 − margin)·μ) it is near slip. Per taxel
  the same test on the taxel's own forces.

What it cannot know is said: ``valid_taxels`` counts the taxels the summary rests on
(fewer than 9: ``partial``; none: ``unknown``, every figure 0). A taxel whose force is
not finite is treated as invalid.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skin.constants import DEFAULT_CONSTANTS, TAXELS_PER_PATCH
from skin.errors import ConfigError

F64 = NDArray[np.float64]
Bools = NDArray[np.bool_]

_ROW, _COL = np.divmod(np.arange(TAXELS_PER_PATCH), 3)
UNIT_XY: F64 = np.stack([_COL - 1.0, _ROW - 1.0], axis=1)
"""(9, 2) taxel centres in pitches, patch frame."""


def _linear_map() -> F64:
    """(27, 6): flattened (9, 3) forces -> ΣFx, ΣFy, ΣFz, Σux·Fz, Σuy·Fz, Σ(ux·Fy − uy·Fx)."""
    w = np.zeros((TAXELS_PER_PATCH, 3, 6))
    w[:, 0, 0] = w[:, 1, 1] = w[:, 2, 2] = 1.0
    w[:, 2, 3] = UNIT_XY[:, 0]
    w[:, 2, 4] = UNIT_XY[:, 1]
    w[:, 1, 5] = UNIT_XY[:, 0]
    w[:, 0, 5] = -UNIT_XY[:, 1]
    return w.reshape(3 * TAXELS_PER_PATCH, 6)


_LINEAR = _linear_map()
SMALLEST_N = 5e-324
"""The smallest positive float64: a normal force at or above it is a normal force."""


def taxel_xy(pitch_m: float) -> F64:
    """(9, 2) centres of the taxels in the patch frame, in metres."""
    out: F64 = UNIT_XY * pitch_m
    return out


@dataclass(frozen=True)
class PatchGeometry:
    """Where a patch's taxels are: their pitch, and where the config places the patch."""

    pitch_m: float = DEFAULT_CONSTANTS.taxel_pitch_m
    position_m: tuple[float, float] = (0.0, 0.0)
    orientation_deg: float = 0.0  # the patch frame turned about z (counter-clockwise)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.pitch_m) and self.pitch_m > 0):
            raise ConfigError("pitch_m", f"must be a positive finite length, got {self.pitch_m!r}")
        if len(self.position_m) != 2 or not all(math.isfinite(v) for v in self.position_m):
            raise ConfigError("position_m", f"must be [x, y] finite metres, got "
                              f"{self.position_m!r}")
        if not math.isfinite(self.orientation_deg):
            raise ConfigError("orientation_deg", f"must be finite, got {self.orientation_deg!r}")

    @property
    def rotation(self) -> F64:
        """(2, 2) R(θ): patch-frame vectors -> placed-frame vectors."""
        theta = math.radians(self.orientation_deg)
        c, s = math.cos(theta), math.sin(theta)
        return np.array([[c, -s], [s, c]])

    def place(self, points_m: ArrayLike) -> F64:
        """``(..., 2)`` points of the patch frame in the placed frame."""
        p = np.asarray(points_m, dtype=np.float64)
        out: F64 = np.asarray(self.position_m) + p @ self.rotation.T
        return out


@dataclass(frozen=True)
class ContactParams:
    """The thresholds and the friction coefficient a contact is judged by."""

    taxel_contact_N: float = 0.12  # a valid taxel with Fz above this is in contact
    onset_N: float = 0.3  # the patch comes into contact when its net Fz reaches this ...
    release_N: float = 0.2  # ... and leaves it when the net Fz falls below this
    friction: float = 0.5  # μ: tangential over normal at which the contact slips
    near_slip_margin: float = 0.2  # near slip from (1 - margin)·μ; slipping ends below it

    def __post_init__(self) -> None:
        for name in ("taxel_contact_N", "onset_N", "release_N", "friction", "near_slip_margin"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) \
                    or not math.isfinite(value):
                raise ConfigError(name, f"must be a finite number, got {value!r}")
        if self.taxel_contact_N < 0:
            raise ConfigError("taxel_contact_N", f"must be >= 0 N, got {self.taxel_contact_N!r}")
        if not 0 < self.release_N <= self.onset_N:
            raise ConfigError("release_N", f"must be in (0, onset_N = {self.onset_N!r}] N, got "
                              f"{self.release_N!r}")
        if self.friction <= 0:
            raise ConfigError("friction", f"must be > 0, got {self.friction!r}")
        if not 0 <= self.near_slip_margin < 1:
            raise ConfigError("near_slip_margin", f"must be in [0, 1), got "
                              f"{self.near_slip_margin!r}")

    @property
    def near_slip_ratio(self) -> float:
        return (1.0 - self.near_slip_margin) * self.friction


class ContactInstant:
    """What ``n`` samples say on their own (no history): see the module docstring.

    The figures a force node's default contact PDO carries are computed at once; the rest
    (torque, placed frame, slip tests) when first read.
    """

    def __init__(self, on: F64, contact: Bools, linear: F64, valid_taxels: NDArray[np.int64],
                 pitch: F64, friction: F64, near_slip_ratio: F64, position: F64,
                 rotation: F64, bounded: bool = False) -> None:
        self.bounded = bounded
        """Every figure is far inside float64's range (a decoder's forces)."""
        self._on = on  # (n, 9, 3) the forces of the taxels in contact, 0 elsewhere
        self._linear = linear  # (n, 6) sums: Fx, Fy, Fz, ux·Fz, uy·Fz, ux·Fy - uy·Fx
        self._pitch = pitch
        self.friction: F64 = friction  # (n,) μ of each row
        self.near_slip_ratio: F64 = near_slip_ratio  # (n,) (1 - margin)·μ of each row
        self._position = position  # (2,) or (n, 2)
        self._rotation = rotation  # (2, 2) or (n, 2, 2)
        self.contact_taxels: Bools = contact  # (n, 9)
        self.valid_taxels: NDArray[np.int64] = valid_taxels  # (n,) taxels it rests on
        # a taxel in contact has Fz > taxel_contact_N >= 0, so their sum is > 0 exactly then
        self.cop_defined: Bools = linear[:, 2] > 0  # (n,) a taxel is in contact
        self.force_N: F64 = linear[:, :3]  # (n, 3) net force over the taxels in contact
        # 0 where no taxel is in contact: 0 / the smallest subnormal is 0; divided first, so
        # a vanishing normal force gives a bounded CoP, never 0·inf
        denominator = np.maximum(linear[:, 2], SMALLEST_N)
        self.cop_m: F64 = linear[:, 3:5] / denominator[:, None] * pitch[:, None]  # 0 if none
        self.tangential_ratio: F64 = np.hypot(linear[:, 0], linear[:, 1]) / denominator
        """(n,) |(Fx, Fy)| / Fz of the net force; 0 where the CoP is not defined (+inf for
        shear over a vanishing normal force, possible only with ``taxel_contact_N`` = 0)."""

    @functools.cached_property
    def contact_area_m2(self) -> F64:
        """(n,) the taxels in contact times a taxel's share of the patch (pitch²)."""
        out: F64 = self.taxels_in_contact * self._pitch ** 2
        return out

    @functools.cached_property
    def known(self) -> Bools:
        """(n,) a valid taxel: the sample says something."""
        out: Bools = self.valid_taxels > 0
        return out

    @functools.cached_property
    def taxels_in_contact(self) -> NDArray[np.int64]:
        """(n,)"""
        out: NDArray[np.int64] = self.contact_taxels.sum(axis=1)
        return out

    def __len__(self) -> int:
        return int(self._linear.shape[0])

    @functools.cached_property
    def near_slip(self) -> Bools:
        """(n,) the net force within the margin of the friction cone, or beyond it."""
        out: Bools = self.cop_defined & (self.tangential_ratio >= self.near_slip_ratio)
        return out

    @functools.cached_property
    def slip(self) -> Bools:
        """(n,) the net force on or beyond the friction cone (the cone alone: the host's
        slip state adds hysteresis, :mod:`skin.contact_state`)."""
        out: Bools = self.cop_defined & (self.tangential_ratio >= self.friction)
        return out

    @functools.cached_property
    def torque_Nm(self) -> F64:
        """(n, 3) about the patch centre, on the surface, patch frame."""
        linear, pitch = self._linear, self._pitch
        with np.errstate(over="ignore"):
            out: F64 = np.stack([linear[:, 4], -linear[:, 3], linear[:, 5]], axis=1) \
                * pitch[:, None]
        return out

    @functools.cached_property
    def cop_placed_m(self) -> F64:
        """(n, 2) the CoP in the placed frame (the patch's position where not defined)."""
        with np.errstate(over="ignore", invalid="ignore"):
            return _turn(self._rotation, self.cop_m) + self._position

    @functools.cached_property
    def force_placed_N(self) -> F64:
        """(n, 3) the net force with (Fx, Fy) turned into the placed frame."""
        out = self.force_N.copy()
        with np.errstate(over="ignore", invalid="ignore"):
            out[:, :2] = _turn(self._rotation, self.force_N[:, :2])
        return out

    @functools.cached_property
    def taxel_shear_N(self) -> F64:
        with np.errstate(over="ignore"):
            out: F64 = np.hypot(self._on[:, :, 0], self._on[:, :, 1])
        return out

    @functools.cached_property
    def taxel_near_slip(self) -> Bools:
        """(n, 9) taxels in contact within the margin of their own friction cone."""
        with np.errstate(over="ignore"):
            out: Bools = self.contact_taxels & (
                self.taxel_shear_N >= self.near_slip_ratio[:, None] * self._on[:, :, 2])
        return out

    @functools.cached_property
    def taxel_slip(self) -> Bools:
        """(n, 9) taxels in contact at or beyond their own friction cone."""
        with np.errstate(over="ignore"):
            out: Bools = self.contact_taxels & (
                self.taxel_shear_N >= self.friction[:, None] * self._on[:, :, 2])
        return out


def _turn(rotation: F64, vectors: F64) -> F64:
    if rotation.ndim == 2:
        out: F64 = vectors @ rotation.T
        return out
    return np.asarray(np.einsum("nij,nj->ni", rotation, vectors), dtype=np.float64)


def _per_row(value: ArrayLike, n: int) -> F64:
    """A scalar, or one value per row, as ``(n,)`` float64."""
    if isinstance(value, np.ndarray) and value.shape == (n,) and value.dtype == np.float64:
        return value
    out: F64 = np.broadcast_to(np.asarray(value, dtype=np.float64), (n,))
    return out


def summarize(force_N: ArrayLike, valid: ArrayLike, *,
              geometry: PatchGeometry | None = None, params: ContactParams | None = None,
              pitch_m: ArrayLike | None = None, position_m: ArrayLike | None = None,
              rotation: ArrayLike | None = None, taxel_contact_N: ArrayLike | None = None,
              friction: ArrayLike | None = None, near_slip_ratio: ArrayLike | None = None,
              bounded: bool = False) -> ContactInstant:
    """The contact of ``n`` samples: ``force_N`` ``(n, 9, 3)`` N, ``valid`` ``(n, 9)``.

    One patch: ``geometry`` and ``params``. Many patches at once (the host's batches):
    per row ``pitch_m`` ``(n,)``, ``position_m`` ``(n, 2)``, ``rotation`` ``(n, 2, 2)``,
    ``taxel_contact_N``, ``friction``, ``near_slip_ratio`` ``(n,)``, any of which
    overrides ``geometry`` or ``params``. ``bounded``: the caller vouches that the forces
    are finite and far inside float64's range (a decoder's, 0 where invalid) and that every
    ``taxel_contact_N`` is positive, so nothing can overflow: the checks are skipped.
    """
    force = np.asarray(force_N, dtype=np.float64)
    if force.ndim != 3 or force.shape[1:] != (TAXELS_PER_PATCH, 3):
        raise ValueError(f"force_N must be (n, 9, 3), got {force.shape}")
    n = force.shape[0]
    ok = np.asarray(valid, dtype=bool)
    if ok.shape != (n, TAXELS_PER_PATCH):
        raise ValueError(f"valid must be ({n}, 9), got {ok.shape}")
    g = geometry or PatchGeometry()
    p = params or ContactParams()
    rows = (_per_row(p.taxel_contact_N if taxel_contact_N is None else taxel_contact_N, n),
            _per_row(g.pitch_m if pitch_m is None else pitch_m, n),
            _per_row(p.friction if friction is None else friction, n),
            _per_row(p.near_slip_ratio if near_slip_ratio is None else near_slip_ratio, n),
            np.asarray(g.position_m if position_m is None else position_m, dtype=np.float64),
            g.rotation if rotation is None else np.asarray(rotation, dtype=np.float64))
    if bounded:
        return summarize_rows(force, ok, *rows)
    with np.errstate(all="ignore"):  # what overflows is found and said, never warned
        if not np.isfinite(force).all():
            finite = np.asarray(np.isfinite(force).all(axis=2), dtype=bool)
            ok = ok & finite
            force = np.where(finite[..., None], force, 0.0)
        instant = summarize_rows(force, ok, *rows, bounded=False)
        linear = instant._linear
        if np.isfinite(linear).all():
            return instant
        # sums beyond float64: such a row says nothing
        beyond = np.asarray(~np.isfinite(linear).all(axis=1), dtype=bool)
        return summarize_rows(np.where(beyond[:, None, None], 0.0, force),
                              ok & ~beyond[:, None], *rows, bounded=False)


def summarize_rows(force: F64, ok: Bools, threshold: F64, pitch: F64, friction: F64,
                   near: F64, position: F64, rotation: F64, bounded: bool = True
                   ) -> ContactInstant:
    """:func:`summarize` without a check: ``(n, 9, 3)`` forces that are finite and far inside
    float64's range, ``(n, 9)`` valid, and per row (``(n,)``) the threshold (> 0), pitch,
    friction and near-slip ratio; the position ``(2,)`` or ``(n, 2)``, the rotation
    ``(2, 2)`` or ``(n, 2, 2)``. The host's batches come this way. ``bounded`` False: the
    caller checks for what overflowed."""
    contact = force[:, :, 2] > threshold[:, None]
    contact &= ok
    on = force * contact[:, :, None]
    linear = on.reshape(-1, 3 * TAXELS_PER_PATCH) @ _LINEAR
    return ContactInstant(on, contact, linear, ok.sum(axis=1), pitch, friction, near,
                          position, rotation, bounded)
