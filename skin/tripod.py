"""The exact tripod model of one taxel, both directions, vectorised.

Geometry (README, "The sensor model"): the lower electrodes are fixed, the upper layer
moves rigidly by u = (ux, uy, uz). Pillar vectors, lower end to upper end:

    z: (ux,      uy,      L + uz)      rest length L
    x: (ux - L,  uy,      L + uz)      rest length √2·L
    y: (ux,      L + uy,  L + uz)      rest length √2·L

Each pillar is linear in engineering strain (Eq. 5): tension T = E·S·e with
e = l'/l - 1. The upper layer is in equilibrium when Σ T_i·n_i equals the force
applied to it. Reported forces are (Fx, Fy, Fz) with Fz > 0 pressing into the
skin, so the applied force in the geometry frame is (Fx, Fy, -Fz).

Everything is computed from the relative resistance change q = R'/R0 - 1 and
from squared-length differences, never by subtracting nearly equal lengths:
e = √(1+q) - 1 is evaluated as q / (1 + √(1+q)).

Arrays are "structure of arrays" internally (one array per component) so the
hot loops are plain element-wise numpy on contiguous memory.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.errors import StrainLimitError

F64 = NDArray[np.float64]

_CHUNK = 8192  # taxels per block: keeps the Newton temporaries in L2 cache
_MAX_NEWTON = 40


def strain_from_ratio_change(q: ArrayLike) -> F64:
    """Engineering strain e = √(1+q) - 1 from q = R'/R0 - 1, without cancellation."""
    q = np.asarray(q, dtype=np.float64)
    return q / (1.0 + np.sqrt(1.0 + q))


def _split(a: F64) -> tuple[F64, F64, F64]:
    return a[..., 0], a[..., 1], a[..., 2]


def _pillar_terms(
    ux: F64, uy: F64, uz: F64, c: SensorConstants
) -> tuple[tuple[F64, F64, F64], tuple[F64, F64, F64]]:
    """Strain and tension per length (T/l') of pillars z, x, y at displacement u."""
    L = c.length_m
    common = uz * (2.0 * L + uz)
    ux2, uy2 = ux * ux, uy * uy
    qz = (ux2 + uy2 + common) / (L * L)
    qx = (ux * (ux - 2.0 * L) + uy2 + common) / (2.0 * L * L)
    qy = (ux2 + uy * (2.0 * L + uy) + common) / (2.0 * L * L)
    ez, ex, ey = (strain_from_ratio_change(q) for q in (qz, qx, qy))
    es = c.axial_stiffness_N
    lz, lx = L, np.sqrt(2.0) * L
    cz = es * ez / (lz * (1.0 + ez))
    cx = es * ex / (lx * (1.0 + ex))
    cy = es * ey / (lx * (1.0 + ey))
    return (ez, ex, ey), (cz, cx, cy)


def _pillar_vectors(
    ux: F64, uy: F64, uz: F64, L: float
) -> tuple[tuple[F64, F64, F64], tuple[F64, F64, F64], tuple[F64, F64, F64]]:
    h = L + uz
    return (ux, uy, h), (ux - L, uy, h), (ux, L + uy, h)


def stiffness_and_residual(
    ux: F64, uy: F64, uz: F64, f: tuple[F64, F64, F64], c: SensorConstants
) -> tuple[tuple[F64, ...], tuple[F64, F64, F64], tuple[F64, F64, F64]]:
    """Tangent stiffness K (6 unique entries), residual Σ T n - f, and strains."""
    L = c.length_m
    strains, tension_per_len = _pillar_terms(ux, uy, uz, c)
    vectors = _pillar_vectors(ux, uy, uz, L)
    es = c.axial_stiffness_N
    rest = (L, np.sqrt(2.0) * L, np.sqrt(2.0) * L)
    r = [-f[0], -f[1], -f[2]]
    per_pillar = []
    for (dx, dy, dz), ci, ei, li in zip(vectors, tension_per_len, strains, rest, strict=True):
        lp = li * (1.0 + ei)
        a = (es / li - ci) / (lp * lp)
        r[0] = r[0] + ci * dx
        r[1] = r[1] + ci * dy
        r[2] = r[2] + ci * dz
        adx, ady = a * dx, a * dy
        per_pillar.append((adx * dx, ady * dy, a * dz * dz, adx * dy, adx * dz, ady * dz))
    zk, xk, yk = per_pillar
    b = tension_per_len[0] + tension_per_len[1] + tension_per_len[2]
    K = tuple(zk[i] + xk[i] + yk[i] + (b if i < 3 else 0.0) for i in range(6))
    return K, (r[0], r[1], r[2]), strains


def solve_sym3(K: tuple[F64, ...], r: tuple[F64, F64, F64]) -> tuple[F64, F64, F64]:
    """x = K⁻¹ r for a batch of symmetric 3×3 matrices, by the adjugate."""
    k11, k22, k33, k12, k13, k23 = K
    a11 = k22 * k33 - k23 * k23
    a12 = k13 * k23 - k12 * k33
    a13 = k12 * k23 - k13 * k22
    a22 = k11 * k33 - k13 * k13
    a23 = k12 * k13 - k11 * k23
    a33 = k11 * k22 - k12 * k12
    inv_det = 1.0 / (k11 * a11 + k12 * a12 + k13 * a13)
    r0, r1, r2 = r
    return (
        (a11 * r0 + a12 * r1 + a13 * r2) * inv_det,
        (a12 * r0 + a22 * r1 + a23 * r2) * inv_det,
        (a13 * r0 + a23 * r1 + a33 * r2) * inv_det,
    )


def _initial_guess(f: tuple[F64, F64, F64], c: SensorConstants) -> tuple[F64, F64, F64]:
    zero = np.zeros(1)
    K, _, _ = stiffness_and_residual(zero, zero, zero, (zero, zero, zero), c)
    return solve_sym3(tuple(k.item() * np.ones_like(f[0]) for k in K), f)


def _peak(strains: tuple[F64, F64, F64]) -> F64:
    return np.maximum(np.maximum(np.abs(strains[0]), np.abs(strains[1])), np.abs(strains[2]))


def _check_strain(peak: F64, limit: float, c: SensorConstants, offset: int) -> None:
    bad = np.flatnonzero(~(peak <= limit))
    if bad.size:
        i = int(bad[0])
        raise StrainLimitError(
            f"force at flat index {offset + i} strains a pillar by {100 * float(peak[i]):.1f} %, "
            f"past the model's limit of {100 * c.max_strain:.0f} % "
            f"({bad.size} taxel-samples in this block)"
        )


def is_stable(K: tuple[F64, ...], uz: F64, L: float) -> NDArray[np.bool_]:
    """Upper layer above the lower one and tangent stiffness positive definite (Sylvester)."""
    k11, k22, k33, k12, k13, k23 = K
    minor2 = k11 * k22 - k12 * k12
    det = k11 * (k22 * k33 - k23 * k23) - k12 * (k12 * k33 - k13 * k23) + k13 * (
        k12 * k23 - k13 * k22
    )
    return (L + uz > 0.0) & (k11 > 0.0) & (minor2 > 0.0) & (det > 0.0)


def _newton(
    u: tuple[F64, F64, F64], f: tuple[F64, F64, F64], c: SensorConstants, tol: float
) -> tuple[tuple[F64, F64, F64], NDArray[np.bool_], F64]:
    """Capped Newton steps from u.

    Returns u, which elements converged to a stable state, and their peak
    pillar strain. Stability and strain are read at the last iterate before
    the final step, which is below ``tol`` and changes neither.
    """
    ux, uy, uz = u
    step_tol = tol * c.length_m
    max_step = 0.05 * c.length_m
    step = np.full(ux.shape, np.inf)
    K: tuple[F64, ...] = ()
    strains = (step, step, step)
    for _ in range(_MAX_NEWTON):
        K, r, strains = stiffness_and_residual(ux, uy, uz, f, c)
        dx, dy, dz = solve_sym3(K, r)
        step = np.abs(dx) + np.abs(dy) + np.abs(dz)
        # Cap each step: near the limit the tangent softens and a full step can
        # jump to the folded equilibrium (upper layer pushed through the lower).
        scale = np.minimum(1.0, max_step / (step + 1e-300))
        ux, uy, uz = ux - dx * scale, uy - dy * scale, uz - dz * scale
        if not np.any(step > step_tol):
            break
    ok = (step <= step_tol) & is_stable(K, uz, c.length_m)
    return (ux, uy, uz), ok, _peak(strains)


def _continuation(
    f: tuple[F64, F64, F64], c: SensorConstants, tol: float, steps: int = 16
) -> tuple[tuple[F64, F64, F64], NDArray[np.bool_], F64]:
    """Follow the stable branch from zero load in small load steps (the slow, sure path)."""
    u = (np.zeros_like(f[0]), np.zeros_like(f[0]), np.zeros_like(f[0]))
    ok = np.ones(f[0].shape, dtype=bool)
    peak = np.zeros_like(f[0])
    for k in range(1, steps + 1):
        scale = k / steps
        u, ok_k, peak = _newton(u, (f[0] * scale, f[1] * scale, f[2] * scale), c, tol)
        ok &= ok_k
    return u, ok, peak


def _displacement_block(
    fx: F64, fy: F64, fz: F64, c: SensorConstants, offset: int, tol: float
) -> tuple[F64, F64, F64]:
    f = (fx, fy, -fz)
    u0 = _initial_guess(f, c)
    # A load whose linear strain is already far past the limit is rejected
    # before Newton can wander.
    _check_strain(_peak(_pillar_terms(*u0, c)[0]), 2.0 * c.max_strain, c, offset)
    (ux, uy, uz), ok, peak = _newton(u0, f, c, tol)
    retry = np.flatnonzero(~ok)
    if retry.size:
        sub = (fx[retry], fy[retry], -fz[retry])
        (rx, ry, rz), ok_retry, peak_retry = _continuation(sub, c, tol)
        ux[retry], uy[retry], uz[retry] = rx, ry, rz
        peak[retry] = peak_retry
        if not np.all(ok_retry):
            i = int(retry[np.flatnonzero(~ok_retry)[0]])
            force = (float(fx[i]), float(fy[i]), float(fz[i]))
            raise StrainLimitError(
                f"force at flat index {offset + i} ({force[0]:.3g}, {force[1]:.3g}, "
                f"{force[2]:.3g}) N has no stable equilibrium: the tripod would collapse "
                f"before reaching it (snap-through); reduce the load"
            )
    _check_strain(peak, c.max_strain, c, offset)
    return ux, uy, uz


def displacement_from_force(
    force_N: ArrayLike, constants: SensorConstants = DEFAULT_CONSTANTS, *, tol: float = 1e-15
) -> F64:
    """Solve equilibrium for the upper-layer displacement u (metres), shape (..., 3).

    ``force_N`` is (..., 3) as (Fx, Fy, Fz), Fz > 0 pressing. Raises
    StrainLimitError if any pillar would pass ``constants.max_strain``.
    """
    force = np.asarray(force_N, dtype=np.float64)
    if force.shape[-1:] != (3,):
        raise ValueError(
            f"force_N must have a last axis of 3 (Fx, Fy, Fz), got shape {force.shape}"
        )
    if not np.all(np.isfinite(force)):
        raise ValueError("force_N contains NaN or infinity")
    flat = force.reshape(-1, 3)
    out = np.empty_like(flat)
    for start in range(0, flat.shape[0], _CHUNK):
        block = np.ascontiguousarray(flat[start : start + _CHUNK].T)
        ux, uy, uz = _displacement_block(block[0], block[1], block[2], constants, start, tol)
        out[start : start + _CHUNK, 0] = ux
        out[start : start + _CHUNK, 1] = uy
        out[start : start + _CHUNK, 2] = uz
    return out.reshape(force.shape)


def ratio_change_from_displacement(
    u_m: ArrayLike, constants: SensorConstants = DEFAULT_CONSTANTS
) -> F64:
    """q = R'/R0 - 1 of pillars (z, x, y) for displacement u, shape (..., 3)."""
    u = np.asarray(u_m, dtype=np.float64)
    ux, uy, uz = _split(u)
    L = constants.length_m
    common = uz * (2.0 * L + uz)
    out = np.empty(u.shape, dtype=np.float64)
    out[..., 0] = (ux * ux + uy * uy + common) / (L * L)
    out[..., 1] = (ux * (ux - 2.0 * L) + uy * uy + common) / (2.0 * L * L)
    out[..., 2] = (ux * ux + uy * (2.0 * L + uy) + common) / (2.0 * L * L)
    return out


def ratio_change_from_force(
    force_N: ArrayLike, constants: SensorConstants = DEFAULT_CONSTANTS
) -> F64:
    """q = R'/R0 - 1 of pillars (z, x, y) under force (Fx, Fy, Fz), shape (..., 3)."""
    return ratio_change_from_displacement(displacement_from_force(force_N, constants), constants)


def resistance_from_force(
    force_N: ArrayLike,
    constants: SensorConstants = DEFAULT_CONSTANTS,
    r0_ohm: ArrayLike | None = None,
) -> F64:
    """Pillar resistances (z, x, y) in ohm under force (Fx, Fy, Fz); Eq. 1 with V = S·l."""
    r0 = constants.nominal_resistance_ohm if r0_ohm is None else np.asarray(r0_ohm, np.float64)
    return r0 * (1.0 + ratio_change_from_force(force_N, constants))


def _force_from_displacement(
    ux: F64, uy: F64, uz: F64, strains: tuple[F64, F64, F64], c: SensorConstants
) -> tuple[F64, F64, F64]:
    L = c.length_m
    es = c.axial_stiffness_N
    rest = (L, np.sqrt(2.0) * L, np.sqrt(2.0) * L)
    fx = fy = fz = np.zeros_like(ux)
    for (dx, dy, dz), e, li in zip(_pillar_vectors(ux, uy, uz, L), strains, rest, strict=True):
        ci = es * e / (li * (1.0 + e))
        fx, fy, fz = fx + ci * dx, fy + ci * dy, fz + ci * dz
    return fx, fy, -fz


@dataclass(frozen=True)
class InverseResult:
    """Forces and which taxels had a physically consistent set of lengths."""

    force_N: F64
    valid: NDArray[np.bool_]


def force_from_ratio_change(
    q: ArrayLike, constants: SensorConstants = DEFAULT_CONSTANTS
) -> InverseResult:
    """Exact 3-axis inverse: q of pillars (z, x, y), shape (..., 3) -> (Fx, Fy, Fz).

    Closed form: the three length equations are solved for u (two of them are
    linear in u after subtracting the first), then F = Σ T_i·n_i. Taxels whose
    lengths cannot meet (no real solution) or whose input is not finite, or
    strained past the limit, are returned as zero force with valid = False.
    """
    qa = np.asarray(q, dtype=np.float64)
    if qa.shape[-1:] != (3,):
        raise ValueError(f"q must have a last axis of 3 (pillars z, x, y), got shape {qa.shape}")
    qz, qx, qy = _split(qa)
    L = constants.length_m
    with np.errstate(invalid="ignore", over="ignore"):
        ux = 0.5 * L * (qz - 2.0 * qx)
        uy = 0.5 * L * (2.0 * qy - qz)
        lateral = ux * ux + uy * uy
        h2 = L * L * (1.0 + qz) - lateral
        strains = (
            strain_from_ratio_change(qz),
            strain_from_ratio_change(qx),
            strain_from_ratio_change(qy),
        )
        valid = np.isfinite(qz) & np.isfinite(qx) & np.isfinite(qy) & (h2 > 0.0)
        for e in strains:
            valid &= np.abs(e) <= constants.max_strain
        safe_h2 = np.where(valid, h2, L * L)
        uz = (L * L * np.where(valid, qz, 0.0) - np.where(valid, lateral, 0.0)) / (
            np.sqrt(safe_h2) + L
        )
        ux = np.where(valid, ux, 0.0)
        uy = np.where(valid, uy, 0.0)
        safe_strains = tuple(np.where(valid, e, 0.0) for e in strains)
    fx, fy, fz = _force_from_displacement(ux, uy, uz, safe_strains, constants)  # type: ignore[arg-type]
    force = np.stack((fx, fy, fz), axis=-1)
    return InverseResult(force_N=force, valid=valid)


def force_from_resistance(
    resistance_ohm: ArrayLike,
    constants: SensorConstants = DEFAULT_CONSTANTS,
    r0_ohm: ArrayLike | None = None,
) -> InverseResult:
    """Exact 3-axis inverse from pillar resistances (z, x, y) in ohm (Eq. 2, then the truss)."""
    r = np.asarray(resistance_ohm, dtype=np.float64)
    r0 = constants.nominal_resistance_ohm if r0_ohm is None else np.asarray(r0_ohm, np.float64)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        q = (r - r0) / r0
    result = force_from_ratio_change(q, constants)
    valid = result.valid & np.all(r > 0.0, axis=-1)
    return InverseResult(force_N=np.where(valid[..., None], result.force_N, 0.0), valid=valid)
