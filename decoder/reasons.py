"""Why a taxel was not decoded: one uint8 code per taxel, and their names."""

from __future__ import annotations

import enum

import numpy as np
from numpy.typing import NDArray

from skin.constants import SensorConstants


class Reason(enum.IntEnum):
    """Per-taxel decode status; 0 is OK, anything else means force 0 N and valid False."""

    OK = 0
    NON_FINITE = 1  # NaN or -inf resistance
    NON_POSITIVE = 2  # resistance < 0
    OPEN = 3  # +inf: open circuit
    SHORT = 4  # exactly 0 ohm: short circuit
    SATURATED = 5  # at or above the ADC's full-scale code
    OUT_OF_RANGE = 6  # physically possible reading outside the decoder's valid/calibrated range
    MISSING = 7  # PDO not received in the cycle (lost, late, duplicated or malformed)
    FAULTY = 8  # reported faulty by the node (EMCY / taxel status): masked by the host
    EXTRAPOLATED = 9  # a trained decoder's input or output is outside its training domain


def reason_name(code: int) -> str:
    """The name of a reason code, e.g. ``reason_name(3) == "OPEN"``."""
    try:
        return Reason(int(code)).name
    except ValueError:
        return f"UNKNOWN({int(code)})"


def saturation_ohm(constants: SensorConstants) -> float:
    """The resistance of the ADC's full-scale code: a reading there is clipped, not measured."""
    return constants.adc_full_scale_code * constants.resistance_lsb_ohm


def classify_resistance(
    resistance_ohm: NDArray[np.float64], constants: SensorConstants
) -> NDArray[np.uint8]:
    """Reason per pillar reading for the electrical faults (OUT_OF_RANGE is the decoder's job).

    Precedence when a taxel has several bad pillars: the lowest non-zero code
    wins (:func:`worst_reason`).
    """
    r = np.asarray(resistance_ohm, dtype=np.float64)
    code = np.zeros(r.shape, dtype=np.uint8)
    code[r >= saturation_ohm(constants)] = Reason.SATURATED
    code[r == 0.0] = Reason.SHORT
    code[r < 0.0] = Reason.NON_POSITIVE
    code[r == np.inf] = Reason.OPEN
    code[np.isnan(r) | (r == -np.inf)] = Reason.NON_FINITE
    return code


def worst_reason(pillar_codes: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """Collapse (..., P) pillar codes to (...) taxel codes: the smallest non-zero code."""
    masked = np.where(pillar_codes == 0, np.uint8(255), pillar_codes)
    best = masked.min(axis=-1)
    return np.where(best == 255, np.uint8(0), best).astype(np.uint8)
