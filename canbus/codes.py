"""Raw UNSIGNED16 resistance codes and per-taxel fault status (objects 0x2000, 0x2004).

A code is ``round(R / lsb)``. Three codes are reserved, so a fault is never mistaken
for a reading: ``0`` short circuit (R below half an LSB), ``0xFFFE`` saturated (a
finite R at or beyond the top of the range), ``0xFFFF`` open circuit (R non-finite)
and "not measured" (pillars x, y in z-only mode).

Taxel status (one UNSIGNED8 per taxel): two bits per pillar, pillar z in bits 0-1, x in
bits 2-3, y in bits 4-5; each pair is 0 ok, 1 open, 2 short, 3 saturated.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

SHORT = 0x0000
SATURATED = 0xFFFE
OPEN = 0xFFFF
FAULT_OK, FAULT_OPEN, FAULT_SHORT, FAULT_SATURATED = 0, 1, 2, 3
FAULT_NAMES = ("ok", "open", "short", "saturated")


def resistance_to_code(resistance_ohm: ArrayLike, lsb_ohm: float) -> NDArray[np.uint16]:
    """Ohms -> UNSIGNED16 codes with the reserved fault codes."""
    r = np.asarray(resistance_ohm, dtype=np.float64)
    finite = np.isfinite(r)
    scaled = np.where(finite, r, 0.0) / lsb_ohm
    codes = np.clip(np.rint(scaled), SHORT, SATURATED).astype(np.uint16)
    codes[~finite] = OPEN
    codes[finite & (r < 0)] = SHORT
    return codes


def code_to_resistance(codes: ArrayLike, lsb_ohm: float) -> NDArray[np.float64]:
    """UNSIGNED16 codes -> ohms; open and saturated become +inf, short 0."""
    c = np.asarray(codes).astype(np.float64)
    r = c * lsb_ohm
    r[c >= SATURATED] = np.inf
    return r


def pillar_faults(codes: ArrayLike) -> NDArray[np.uint8]:
    """Codes -> fault per pillar (0 ok, 1 open, 2 short, 3 saturated), same shape."""
    c = np.asarray(codes)
    faults = np.zeros(c.shape, dtype=np.uint8)
    faults[c == OPEN] = FAULT_OPEN
    faults[c == SHORT] = FAULT_SHORT
    faults[c == SATURATED] = FAULT_SATURATED
    return faults


def taxel_status(codes: ArrayLike, measured: int) -> NDArray[np.uint8]:
    """``(..., 9, 3)`` codes -> ``(..., 9)`` status bytes over the first ``measured`` pillars."""
    faults = pillar_faults(np.asarray(codes)[..., :measured]).astype(np.uint8)
    shifts = (2 * np.arange(measured)).astype(np.uint8)
    status: NDArray[np.uint8] = np.bitwise_or.reduce(faults << shifts, axis=-1).astype(np.uint8)
    return status
