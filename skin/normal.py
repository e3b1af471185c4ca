"""z-only mode: the exact normal force from the vertical pillar alone.

The paper's experiment reads only pillar z. One resistance cannot fix three
force components, so z-only mode assumes the load is purely normal
(Fx = Fy = 0) -- the paper's protocol -- and solves exactly under that
assumption: find u with |d_z| = l'_z and zero lateral force, then Fz.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.tripod import (
    F64,
    InverseResult,
    is_stable,
    solve_sym3,
    stiffness_and_residual,
    strain_from_ratio_change,
)

_MAX_ITER = 40


def _solve3(
    rows: tuple[tuple[F64, F64, F64], tuple[F64, F64, F64], tuple[F64, F64, F64]],
    rhs: tuple[F64, F64, F64],
) -> tuple[F64, F64, F64]:
    """Cramer's rule for a batch of general 3×3 systems."""
    (a, b, c), (d, e, f), (g, h, i) = rows
    co1, co2, co3 = e * i - f * h, f * g - d * i, d * h - e * g
    inv_det = 1.0 / (a * co1 + b * co2 + c * co3)
    r1, r2, r3 = rhs
    x = (r1 * co1 + r2 * (c * h - b * i) + r3 * (b * f - c * e)) * inv_det
    y = (r1 * co2 + r2 * (a * i - c * g) + r3 * (c * d - a * f)) * inv_det
    z = (r1 * co3 + r2 * (b * g - a * h) + r3 * (a * e - b * d)) * inv_det
    return x, y, z


def _unit_normal_response(c: SensorConstants) -> tuple[float, float, float]:
    zero = np.zeros(1)
    K, _, _ = stiffness_and_residual(zero, zero, zero, (zero, zero, zero), c)
    K1 = tuple(k.item() * np.ones(1) for k in K)
    v = solve_sym3(K1, (zero, zero, -np.ones(1)))
    return float(v[0][0]), float(v[1][0]), float(v[2][0])


def normal_force_from_ratio_change(
    qz: ArrayLike, constants: SensorConstants = DEFAULT_CONSTANTS, *, tol: float = 1e-15
) -> InverseResult:
    """Exact Fz (N, > 0 pressing) from q = R'_z/R0_z - 1 of pillar z, assuming no shear.

    Returns ``force_N`` of the same shape as ``qz`` and a valid mask; invalid
    taxels (non-finite input, past the strain limit, no stable equilibrium)
    get 0 N and valid = False.
    """
    q = np.asarray(qz, dtype=np.float64)
    flat = q.reshape(-1)
    c = constants
    L = c.length_m
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        ez = strain_from_ratio_change(flat)
        valid = np.isfinite(flat) & (np.abs(ez) <= c.max_strain)
        qs = np.where(valid, flat, 0.0)
        ez = np.where(valid, ez, 0.0)
        vx, vy, vz = _unit_normal_response(c)
        scale = L * ez / vz
        ux, uy, uz = scale * vx, scale * vy, scale * vz
        zero = np.zeros_like(qs)
        step = np.full(qs.shape, np.inf)
        for _ in range(_MAX_ITER):
            K, r, _ = stiffness_and_residual(ux, uy, uz, (zero, zero, zero), c)
            k11, k22, _, k12, k13, k23 = K
            g1 = ux * ux + uy * uy + uz * (2.0 * L + uz) - L * L * qs
            rows = ((2.0 * ux, 2.0 * uy, 2.0 * (L + uz)), (k11, k12, k13), (k12, k22, k23))
            dx, dy, dz = _solve3(rows, (g1, r[0], r[1]))
            step = np.abs(dx) + np.abs(dy) + np.abs(dz)
            cap = np.minimum(1.0, 0.05 * L / (step + 1e-300))
            ux, uy, uz = ux - dx * cap, uy - dy * cap, uz - dz * cap
            if not np.any(step > tol * L):
                break
        K, r, strains = stiffness_and_residual(ux, uy, uz, (zero, zero, zero), c)
        peak = np.maximum(np.maximum(np.abs(strains[0]), np.abs(strains[1])), np.abs(strains[2]))
        valid &= (step <= tol * L) & is_stable(K, uz, L) & (peak <= c.max_strain)
        force = np.where(valid, -r[2], 0.0)
    return InverseResult(force_N=force.reshape(q.shape), valid=valid.reshape(q.shape))


def normal_force_from_resistance(
    resistance_ohm: ArrayLike,
    constants: SensorConstants = DEFAULT_CONSTANTS,
    r0_ohm: ArrayLike | None = None,
) -> InverseResult:
    """Exact Fz from the resistance of pillar z (ohm), assuming no shear."""
    r = np.asarray(resistance_ohm, dtype=np.float64)
    r0 = (
        constants.nominal_resistance_ohm[0] if r0_ohm is None else np.asarray(r0_ohm, np.float64)
    )
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        q = (r - r0) / r0
    result = normal_force_from_ratio_change(q, constants)
    valid: NDArray[np.bool_] = result.valid & (r > 0.0)
    return InverseResult(force_N=np.where(valid, result.force_N, 0.0), valid=valid)
