"""The exact per-taxel inverse of the sensor model, as the decoders use it.

:func:`make_inverse` builds, for one set of constants, one R0 and one pillar
count, the z-only table inverse (decoder.ztable) or the 3-axis closed form
(decoder.tripod3), with everything that depends only on those computed once.
Each has two paths over folded resistances (n, 9, P):

- ``fast(r)``: the forces when every reading decodes, else None. It masks
  nothing; one min and one max of the grid coordinates or ratios decide.
- ``full(r)``: forces with 0 N where a taxel does not decode, and that mask;
  :func:`taxel_reasons` then says why.

Both compute a decodable taxel with the same operations, so they agree exactly
(tests/decoder/test_fast_path.py).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from decoder.reasons import Reason, classify_resistance, saturation_ohm, worst_reason
from decoder.tripod3 import TripodInverse
from decoder.ztable import NormalInverse
from skin.constants import TAXELS_PER_PATCH as T
from skin.constants import SensorConstants

F64 = NDArray[np.float64]
Inverse = NormalInverse | TripodInverse


def make_inverse(constants: SensorConstants, r0_ohm: F64, pillars: int) -> Inverse:
    """The inverse for P = 1 (Fz (n, 9) out) or P = 3 (forces (n, 9, 3) out)."""
    if pillars == 1:
        return NormalInverse(constants, r0_ohm, saturation_ohm(constants))
    return TripodInverse(constants, r0_ohm, saturation_ohm(constants))


def taxel_reasons(r: F64, ok: NDArray[np.bool_], constants: SensorConstants) -> NDArray[np.uint8]:
    """Reasons (n, 9) from readings (n, 9, P) and the decodable mask (n, 9).

    A taxel that is not decodable gets its worst electrical fault, or
    OUT_OF_RANGE when every pillar reading is plausible.
    """
    reason = np.zeros(ok.shape, dtype=np.uint8)
    bad = np.flatnonzero(~ok)
    if bad.size:
        rows = r.reshape(-1, r.shape[-1])[bad]
        code = worst_reason(classify_resistance(rows, constants))
        reason.reshape(-1)[bad] = np.where(code == 0, np.uint8(Reason.OUT_OF_RANGE), code)
    return reason


def to_force(y: F64, pillars: int) -> F64:
    """Per-taxel outputs -> forces (n, 9, 3): Fz as (n, 9) or (9,) in z-only mode, all three
    components as (n, 27), (27,) or (n, 9, 3) in 3-axis mode."""
    if pillars == 3:
        return y.reshape(-1, T, 3)
    fz = y.reshape(-1, T)
    force = np.zeros((fz.shape[0], T, 3))
    force[..., 2] = fz
    return force


def features(force: F64, pillars: int) -> F64:
    """Per-taxel outputs as rows, taxel-major: Fz (n, 9) in z-only mode (from Fz (n, 9) or
    forces (n, 9, 3)), all components (n, 27) in 3-axis mode. The inverse of :func:`to_force`."""
    if pillars == 1:
        fz: F64 = force[..., 2] if force.ndim == 3 else force
        return fz.reshape(fz.shape[0], T)
    return force.reshape(force.shape[0], 3 * T)


def solve(
    inverse: Inverse, r: F64, constants: SensorConstants
) -> tuple[F64, NDArray[np.uint8]]:
    """Resistances (n, 9, P) -> forces (n, 9, 3) and reasons (n, 9); invalid taxels 0 N."""
    pillars = r.shape[-1]
    out = inverse.fast(r)
    if out is not None:
        return to_force(out, pillars), np.zeros(r.shape[:2], dtype=np.uint8)
    out, ok = inverse.full(r)
    return to_force(out, pillars), taxel_reasons(r, ok, constants)


def exact_inverse(
    r: F64, constants: SensorConstants, r0: F64
) -> tuple[F64, NDArray[np.uint8]]:
    """:func:`solve` with an inverse built for this call (decoders cache theirs)."""
    return solve(make_inverse(constants, r0, r.shape[-1]), r, constants)
