"""A patch's rest resistances from calibration data, and the frame a calibrated model reads.

The tare is the mean reading of each pillar over the samples whose reference force is
zero (every taxel's |F| at most ``rest_N``), rounded to REAL32 as a patch's 0x2002
holds it. A calibrated model is fitted on readings normalised to its decoder's nominal
R0, ``x = R · r0 / rest``: exactly what the host feeds a decoder once the patch (0x2002)
or the config (``r0_ohm``) reports ``rest``, since the host scales every reading by
``r0 / R0 reported``. A host tare at rest (``skin tare``) reaches the same frame.
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
    """The rest of one patch: ``rest_ohm`` (9, P), REAL32-rounded, from ``samples`` rows."""

    rest_ohm: F64
    samples: int
    noise_ohm: F64  # (9, P) standard deviation of the rest readings
    rest_N: float


def real32(values: ArrayLike) -> F64:
    """Each value as a REAL32 read back as its shortest decimal, as a host reads 0x2002."""
    a = np.asarray(values, dtype=np.float64)
    out = np.array([float(str(np.float32(v))) for v in a.ravel().tolist()], dtype=np.float64)
    return out.reshape(a.shape)


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
    return Tare(real32(at_rest.mean(axis=0)), count, at_rest.std(axis=0), rest_N)


def nominal_r0(constants: SensorConstants, pillars: int) -> F64:
    """(9, P) the R0 at which a decoder built with ``constants`` reads zero force."""
    r0: F64 = np.broadcast_to(constants.nominal_resistance_ohm[:pillars],
                              (9, pillars)).astype(np.float64)
    return r0


def normalise(resistance_ohm: ArrayLike, rest_ohm: ArrayLike, r0_ohm: ArrayLike) -> F64:
    """Readings in the frame of a decoder whose zero-force resistance is ``r0_ohm``: what
    the host gives it for a patch that reports ``rest_ohm`` (``r0 / rest`` per pillar; a
    rest within REAL32 precision of r0 is r0, as the host's baseline takes it)."""
    r0 = np.asarray(r0_ohm, dtype=np.float64)
    rest = np.asarray(rest_ohm, dtype=np.float64)
    scale = r0 / np.where(np.isclose(rest, r0, rtol=1e-6, atol=0.0), r0, rest)
    out: F64 = np.asarray(resistance_ohm, dtype=np.float64) * scale
    return out
