"""A patch's contact from its taxel forces: net force, torque, centre of pressure, slip.

Pure, vectorised numpy (float64) over ``n`` samples of one or many patches. The host
summarises every published sample with it and the simulator's truth uses it on the true
loads, so both measure the same thing.

Geometry. Taxel k sits at column k % 3, row k // 3 of the patch's grid, centre
((k % 3 - 1)·pitch, (k // 3 - 1)·pitch) in the *patch frame* (x right, y up seen from
above, z out of the skin: Fz > 0 presses in; :func:`taxel_xy` places them
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

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skin.constants import DEFAULT_CONSTANTS, TAXELS_PER_PATCH
from skin.contact_sums import (
    F64,
    FX,
    FY,
    SMALLEST_N,
    UNIT_XY,
    Bools,
    ContactInstant,
    RowParams,
    SumsKernel,
)
from skin.errors import ConfigError

__all__ = ["F64", "SMALLEST_N", "UNIT_XY", "Bools", "ContactInstant", "ContactParams",
           "PatchGeometry", "RowParams", "summarize", "summarize_rows", "taxel_xy"]


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
    force = np.array(force_N, dtype=np.float64)  # a copy: the summary reads it later
    if force.ndim != 3 or force.shape[1:] != (TAXELS_PER_PATCH, 3):
        raise ValueError(f"force_N must be (n, 9, 3), got {force.shape}")
    n = force.shape[0]
    ok = np.array(valid, dtype=bool)
    if ok.shape != (n, TAXELS_PER_PATCH):
        raise ValueError(f"valid must be ({n}, 9), got {ok.shape}")
    g = geometry or PatchGeometry()
    p = params or ContactParams()
    rows = RowParams(
        _per_row(p.taxel_contact_N if taxel_contact_N is None else taxel_contact_N, n),
        _per_row(g.pitch_m if pitch_m is None else pitch_m, n),
        _per_row(p.friction if friction is None else friction, n),
        _per_row(p.near_slip_ratio if near_slip_ratio is None else near_slip_ratio, n),
        np.asarray(g.position_m if position_m is None else position_m, dtype=np.float64),
        g.rotation if rotation is None else np.asarray(rotation, dtype=np.float64))
    return summarize_rows(force, ok, rows, bounded=bounded)


def summarize_rows(force: F64, ok: Bools, rows: RowParams, *, bounded: bool = False
                   ) -> ContactInstant:
    """:func:`summarize` of ``(n, 9, 3)`` float64 forces and ``(n, 9)`` valid that the
    caller no longer changes, with each row's parameters."""
    kernel = SumsKernel(rows)
    if bounded:
        return kernel.instant(force, ok, bounded=True)
    with np.errstate(all="ignore"):  # what overflows is found and said, never warned
        finite = np.asarray(np.isfinite(force).all(axis=2), dtype=bool)
        if not finite.all():
            ok = ok & finite
            force = np.where(finite[..., None], force, 0.0)
        kernel.run(force, ok, checked=True)
        sums = kernel.sums
        twist = sums[FY, :, 1] - sums[FX, :, 2]  # the torque's Σ x·Fy − Σ y·Fx
        beyond = ~np.asarray(np.isfinite(sums[:3]).all(axis=(0, 2)) & np.isfinite(twist),
                             dtype=bool)
        if beyond.any():  # sums (or the torque) beyond float64: such a row says nothing
            ok = ok & ~beyond[:, None]
            force = np.where(beyond[:, None, None], 0.0, force)
        return kernel.instant(force, ok, bounded=False, checked=True)
