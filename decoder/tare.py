"""A patch's rest resistances from calibration data, and the frame a calibrated model reads.

The tare is the mean reading of each pillar over the samples whose reference force is
zero (every taxel's |F| at most ``rest_N``), rounded to the milliohm as a patch's 0x2002
holds it (UNSIGNED32 in mOhm, ``canbus.patch_constants``). A calibrated model is fitted
on readings normalised to its decoder's nominal R0, ``x = R · r0 / rest``: exactly what
the host feeds a decoder once the patch (0x2002) or the config (``r0_ohm``) reports
``rest``, since the host scales every reading by ``r0 / R0 reported``. A host tare at
rest (``skin tare``) reaches the same frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skin.constants import SensorConstants
from skin.errors import DecodeError

F64 = NDArray[np.float64]
MIN_REST_SAMPLES = 10
"""Fewer rest samples than this give no tare: the mean would carry the read noise."""
DEFAULT_REST_N = 0.01


@dataclass(frozen=True)
class Tare:
    """The rest of one patch: ``rest_ohm`` (9, P), in whole mOhm, from ``samples`` rows."""

    rest_ohm: F64
    samples: int
    noise_ohm: F64  # (9, P) standard deviation of the rest readings
    rest_N: float


R0_OHM_PER_COUNT = 1e-3
"""0x2002 counts milliohms (``canbus.patch_constants.R0_SCALE``)."""


def as_reported(values: ArrayLike) -> F64:
    """Each value as a patch's 0x2002 holds it and a host reads it back: whole mOhm."""
    a = np.asarray(values, dtype=np.float64)
    out: F64 = np.rint(a / R0_OHM_PER_COUNT) / round(1 / R0_OHM_PER_COUNT)
    return out


def rest_rows(force_N: ArrayLike, rest_N: float = DEFAULT_REST_N) -> NDArray[np.bool_]:
    """(n,) samples whose reference force is at most ``rest_N`` on every taxel."""
    f = np.asarray(force_N, dtype=np.float64)
    rows: NDArray[np.bool_] = np.all(np.linalg.norm(f, axis=-1) <= rest_N, axis=-1)
    return rows


def tare_at_rest(resistance_ohm: ArrayLike, force_N: ArrayLike,
                 rest_N: float = DEFAULT_REST_N) -> Tare | None:
    """The tare of one patch from ``(n, 9, P)`` readings and ``(n, 9, 3)`` reference forces,
    over the rest samples whose every reading is a finite resistance; None with fewer than
    :data:`MIN_REST_SAMPLES` of them."""
    if not rest_N >= 0:
        raise DecodeError(f"rest_N must be >= 0 N, got {rest_N!r}")
    r = np.asarray(resistance_ohm, dtype=np.float64)
    readable = np.all(np.isfinite(r) & (r > 0), axis=(-2, -1))  # no open or shorted pillar
    rows = rest_rows(force_N, rest_N) & readable
    count = int(rows.sum())
    if count < MIN_REST_SAMPLES:
        return None
    at_rest = r[rows]
    return Tare(as_reported(at_rest.mean(axis=0)), count, at_rest.std(axis=0), rest_N)


def nominal_r0(constants: SensorConstants, pillars: int) -> F64:
    """(9, P) the R0 at which a decoder built with ``constants`` reads zero force."""
    r0: F64 = np.broadcast_to(constants.nominal_resistance_ohm[:pillars],
                              (9, pillars)).astype(np.float64)
    return r0


def normalise(resistance_ohm: ArrayLike, rest_ohm: ArrayLike, r0_ohm: ArrayLike) -> F64:
    """Readings in the frame of a decoder whose zero-force resistance is ``r0_ohm``: what
    the host gives it for a patch that reports ``rest_ohm`` (``r0 / rest`` per pillar; a
    rest within a milliohm's rounding of r0 is r0, as the host's baseline takes it)."""
    r0 = np.asarray(r0_ohm, dtype=np.float64)
    rest = np.asarray(rest_ohm, dtype=np.float64)
    scale = r0 / np.where(np.abs(rest - r0) <= R0_OHM_PER_COUNT / 2, r0, rest)
    out: F64 = np.asarray(resistance_ohm, dtype=np.float64) * scale
    return out
