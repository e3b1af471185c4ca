"""The oracle: the exact inverse with the scene's true forward model and crosstalk.

It knows what no decoder may know (the crosstalk matrix M of the scene), so
its error is the floor set by noise and quantisation alone: exact per-taxel
inverse to F_eff, then M F = F_eff solved per sample and component. The
caller passes M as an array; the decoder package never imports the simulator.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from decoder.physics import exact_inverse
from decoder.protocol import Decoded, fold_resistance, unfold
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.errors import DecodeError


def oracle_decode(
    resistance_ohm: ArrayLike,
    crosstalk: ArrayLike,
    constants: SensorConstants = DEFAULT_CONSTANTS,
    r0_ohm: ArrayLike | None = None,
) -> Decoded:
    """Forces from resistances (samples, [patches,] 9, P) knowing the (9, 9) crosstalk matrix."""
    m = np.asarray(crosstalk, dtype=np.float64)
    if m.shape != (9, 9) or not np.all(np.isfinite(m)):
        raise DecodeError(f"crosstalk must be a finite (9, 9) matrix, got shape {m.shape}")
    r, lead = fold_resistance(resistance_ohm)
    pillars = r.shape[-1]
    r0 = (constants.nominal_resistance_ohm[:pillars] if r0_ohm is None
          else np.asarray(r0_ohm, dtype=np.float64))
    effective, reason = exact_inverse(r, constants, r0)
    try:
        force = np.asarray(np.linalg.solve(m, effective), dtype=np.float64)
    except np.linalg.LinAlgError as err:
        raise DecodeError("the crosstalk matrix is singular") from err
    valid = reason == 0
    force[~valid] = 0.0
    return unfold(Decoded(force_N=force, valid=valid, reason=reason), lead)
