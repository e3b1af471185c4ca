"""The paper's small-strain approximation, and how far it is from the exact model.

The paper takes each pillar's length change as the electrode's displacement
along one axis (Δl_i ≈ Δ_i) and reads each force component from one pillar
by Eq. 9: F_i = E·S·(1 - √(R'_i/R_i)). Pillar z gives Fz (compression is
pressing), pillar x gives Fx (a push along +x shortens it), pillar y gives Fy
(a push along +y lengthens it). That ignores both the 45° lean of pillars x
and y and the large-rotation geometry, so its error does not vanish even at
small strain; ``linear_truss_force`` keeps the right geometry but linearises,
which separates the two sources of error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.tripod import (
    F64,
    ratio_change_from_force,
    stiffness_and_residual,
    strain_from_ratio_change,
)

PAPER_SIGNS = np.array([-1.0, 1.0, -1.0])
"""Sign mapping pillar strain (x, y, z) to (Fx, Fy, Fz) in the paper's reading."""


def paper_force_from_ratio_change(
    q: ArrayLike, constants: SensorConstants = DEFAULT_CONSTANTS
) -> F64:
    """Eq. 9 per pillar: (Fx, Fy, Fz) from q of pillars (z, x, y)."""
    e = strain_from_ratio_change(q)
    strains_xyz = np.stack((e[..., 1], e[..., 2], e[..., 0]), axis=-1)
    return constants.axial_stiffness_N * PAPER_SIGNS * strains_xyz


def linear_truss_force(q: ArrayLike, constants: SensorConstants = DEFAULT_CONSTANTS) -> F64:
    """Right geometry, small strain: u from the linearised length equations, F = K0·u."""
    qa = np.asarray(q, dtype=np.float64)
    L = constants.length_m
    e = strain_from_ratio_change(qa)
    # Linearised lengths: Δl_z = uz, Δl_x = (uz - ux)/√2, Δl_y = (uy + uz)/√2.
    dl_z = L * e[..., 0]
    dl_x = np.sqrt(2.0) * L * e[..., 1]
    dl_y = np.sqrt(2.0) * L * e[..., 2]
    uz = dl_z
    ux = uz - np.sqrt(2.0) * dl_x
    uy = np.sqrt(2.0) * dl_y - uz
    zero = np.zeros(1)
    K, _, _ = stiffness_and_residual(zero, zero, zero, (zero, zero, zero), constants)
    k11, k22, k33, k12, k13, k23 = (float(k[0]) for k in K)
    fx = k11 * ux + k12 * uy + k13 * uz
    fy = k12 * ux + k22 * uy + k23 * uz
    fz = k13 * ux + k23 * uy + k33 * uz
    return np.stack((fx, fy, -fz), axis=-1)


@dataclass(frozen=True)
class ApproximationRow:
    """Error of the approximations for one load direction at one peak strain."""

    load: str
    strain_pct: float
    force_N: float | None
    paper_err_pct: float | None
    linear_err_pct: float | None


LOAD_DIRECTIONS: dict[str, tuple[float, float, float]] = {
    "press": (0.0, 0.0, 1.0),
    "pull": (0.0, 0.0, -1.0),
    "shear +x": (1.0, 0.0, 0.0),
    "shear -y": (0.0, -1.0, 0.0),
    "press + shear": (1.0, 1.0, 2.0),
}


def _peak_strain(force: F64, constants: SensorConstants) -> float:
    q = ratio_change_from_force(force, constants)
    return float(np.max(np.abs(strain_from_ratio_change(q))))


def force_at_strain(
    direction: ArrayLike, strain: float, constants: SensorConstants = DEFAULT_CONSTANTS
) -> float | None:
    """Magnitude along ``direction`` at which the most strained pillar reaches ``strain``.

    None if the tripod has no stable equilibrium before that strain.
    """
    from skin.errors import StrainLimitError

    unit = np.asarray(direction, dtype=np.float64)
    unit = unit / np.linalg.norm(unit)
    lo, hi = 0.0, 1.0
    while True:
        try:
            if _peak_strain(unit * hi, constants) >= strain:
                break
        except StrainLimitError:
            break
        lo, hi = hi, 2.0 * hi
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        try:
            reached = _peak_strain(unit * mid, constants) >= strain
        except StrainLimitError:
            reached = True
        lo, hi = (lo, mid) if reached else (mid, hi)
    try:
        peak = _peak_strain(unit * lo, constants)
    except StrainLimitError:
        return None
    return lo if abs(peak - strain) < 1e-6 else None


def approximation_table(
    strains: tuple[float, ...] = (0.05, 0.10, 0.20),
    constants: SensorConstants = DEFAULT_CONSTANTS,
) -> list[ApproximationRow]:
    """The approximations' relative force error (vector norm) per load and strain."""
    rows = []
    for name, direction in LOAD_DIRECTIONS.items():
        for strain in strains:
            magnitude = force_at_strain(direction, strain, constants)
            if magnitude is None:
                rows.append(ApproximationRow(name, 100 * strain, None, None, None))
                continue
            unit = np.asarray(direction) / np.linalg.norm(direction)
            force = unit * magnitude
            q = ratio_change_from_force(force, constants)
            errs = [
                100 * float(np.linalg.norm(approx - force) / magnitude)
                for approx in (
                    paper_force_from_ratio_change(q, constants),
                    linear_truss_force(q, constants),
                )
            ]
            rows.append(ApproximationRow(name, 100 * strain, magnitude, errs[0], errs[1]))
    return rows
