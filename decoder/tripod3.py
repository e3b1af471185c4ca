"""Fast exact 3-axis inverse: skin.tripod.force_from_ratio_change, specialised.

Same closed form, written in units of the pillar length L with per-pillar
ratios p = R/R0 = 1 + q (pillars z, x, y):

    u = q_z/2 - q_x,  w = q_z/2 - q_y,  h = sqrt(p_z - u² - w²)
        (the upper layer's offset (u, -w) and height h over L: the two length
        equations are linear in the offset once the first is subtracted)
    c_i = k_i·q_i / (p_i + s_i),  s_i = sqrt(p_i),  k = E·S·(1, 1/√2, 1/√2)
        (tension times L over the current length, E·S·(1 - 1/s_i)/g_i, without
        the cancellation: (1 + s)·s = p + s; g = 1 for pillar z, √2 diagonal)
    F = (C·u - c_x,  c_y - C·w,  -C·h),  C = c_z + c_x + c_y

A taxel is decodable when every pillar is within the strain limit
((1 - e_max)² <= p <= (1 + e_max)²) and the lengths meet (h² > 0).

Work arrays are (3, taxels), so each step is one operation on one pillar or on
all three, with the constants tiled to match (nothing broadcasts). Batches go
pillar-major in chunks that stay in cache; a few samples stay taxel-major (the
arrays are transposed views); one patch-sample on the fast path is computed in
Python floats, which is faster than thirty numpy calls on 27 numbers and gives
the same bits. Checked against skin.tripod to 1e-12 N by
tests/decoder/test_analytic.py, and path against path by test_fast_path.py.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from skin.constants import TAXELS_PER_PATCH as T
from skin.constants import SensorConstants

F64 = NDArray[np.float64]
CHUNK = 8190  # taxels per chunk (whole patches): the temporaries stay in cache
SMALL = 64  # up to this many taxels, a transposed view beats a pillar-major copy
SCALAR = T  # up to this many taxels (one patch-sample), Python floats beat numpy calls
_ONE = np.array(1.0)
_HALF = np.array(0.5)


class TripodInverse:
    """Resistances (n, 9, 3) of pillars (z, x, y) in ohm -> forces (n, 9, 3) (Fx, Fy, Fz).

    For one set of constants and R0 (pillar R0 (3,) or per taxel (9, 3)). A
    reading at or above ``saturation_ohm`` is not decodable when the strain
    limit lets a pillar reach it.
    """

    def __init__(self, constants: SensorConstants, r0_ohm: F64, saturation_ohm: float) -> None:
        r0 = np.broadcast_to(np.asarray(r0_ohm, dtype=np.float64), (T, 3))
        es = constants.axial_stiffness_N
        neg_k = -np.array([es, es / math.sqrt(2.0), es / math.sqrt(2.0)])  # see _force
        # Constants tiled over a chunk, taxel-major and pillar-major: no step broadcasts.
        self._inv_r0 = np.tile(1.0 / r0, (CHUNK // T, 1))  # (CHUNK, 3)
        self._neg_k = np.tile(neg_k, (CHUNK, 1))
        self._inv_r0_t = np.ascontiguousarray(self._inv_r0.T)  # (3, CHUNK)
        self._neg_k_t = np.ascontiguousarray(self._neg_k.T)
        e = constants.max_strain
        self._p_lo, self._p_hi = (1.0 - e) ** 2, (1.0 + e) ** 2
        self._sat = saturation_ohm
        self._sat_reachable = bool(self._p_hi * np.max(r0) * (1.0 + 1e-9) >= saturation_ohm)
        # The same constants as Python floats, for _fast_scalar.
        self._inv_r0_rows: list[tuple[float, float, float]] = [
            (a, b, c) for a, b, c in (1.0 / r0).tolist()]
        nkz, nkx, nky = neg_k.tolist()
        self._neg_k_row = (nkz, nkx, nky)
        self._sat_scalar = saturation_ohm if self._sat_reachable else math.inf

    def fast(self, r: F64) -> F64 | None:
        """Forces (n, 9, 3) if every taxel is decodable, else None (nothing is masked here)."""
        x = r.reshape(-1, 3)
        n = x.shape[0]
        if n <= SCALAR:
            return self._fast_scalar(x)
        out = np.empty(x.shape)
        if 0 < n <= CHUNK:
            ok = self._fast_chunk(x, out)
        else:
            ok = all(self._fast_chunk(x[i:i + CHUNK], out[i:i + CHUNK])
                     for i in range(0, n, CHUNK))
        return out.reshape(-1, T, 3) if ok else None

    def _fast_chunk(self, x: F64, out: F64) -> bool:
        p, neg_k = self._ratio(x)
        flat = p.ravel(order="K")
        # argmin/argmax stop at the first NaN, so a NaN fails these tests too.
        if not (flat[flat.argmin()] >= self._p_lo and flat[flat.argmax()] <= self._p_hi):
            return False
        if self._sat_reachable and not np.max(x) < self._sat:
            return False
        q = p - _ONE
        u, w, h2 = _offset(p, q)
        if not h2[h2.argmin()] > 0.0:
            return False
        _force(p, q, u, w, h2, neg_k, out)
        return True

    def _fast_scalar(self, x: F64) -> F64 | None:
        """fast() of one patch-sample (m <= 9 taxels, (m, 3)) in Python floats.

        The operations and their order are those of _ratio, _offset and _force,
        so the result has the same bits: IEEE 754 rounds each +, -, *, / and
        sqrt correctly, in numpy and in Python alike.
        """
        lo, hi, sat = self._p_lo, self._p_hi, self._sat_scalar
        kz, kx, ky = self._neg_k_row
        sqrt = math.sqrt
        out: list[float] = []
        for (rz, rx, ry), (iz, ix, iy) in zip(x.tolist(), self._inv_r0_rows, strict=False):
            pz, px, py = rz * iz, rx * ix, ry * iy
            # NaN compares False, so it fails here too.
            if not (lo <= pz <= hi and lo <= px <= hi and lo <= py <= hi
                    and rz < sat and rx < sat and ry < sat):
                return None
            qz, qx, qy = pz - 1.0, px - 1.0, py - 1.0
            hz = qz * 0.5
            u, w = hz - qx, hz - qy
            h2 = (pz - u * u) - w * w
            if not h2 > 0.0:
                return None
            cz = qz / (sqrt(pz) + pz) * kz
            cx = qx / (sqrt(px) + px) * kx
            cy = qy / (sqrt(py) + py) * ky
            total = cz + cx + cy
            out += (cx - total * u, total * w - cy, total * sqrt(h2))
        return np.array(out).reshape(-1, T, 3)

    def full(self, r: F64) -> tuple[F64, NDArray[np.bool_]]:
        """Forces (n, 9, 3) with 0 N where a taxel is not decodable, and that mask (n, 9)."""
        x = r.reshape(-1, 3)
        out = np.empty(x.shape)
        ok = np.empty(x.shape[0], dtype=bool)
        for i in range(0, x.shape[0], CHUNK):
            xk, okk = x[i:i + CHUNK], ok[i:i + CHUNK]
            p, neg_k = self._ratio(xk)
            # NaN compares False: non-finite readings are not decodable.
            np.all((p >= self._p_lo) & (p <= self._p_hi), axis=0, out=okk)
            if self._sat_reachable:
                okk &= np.all(xk < self._sat, axis=1)
            np.copyto(p, 1.0, where=~okk)
            q = p - _ONE
            u, w, h2 = _offset(p, q)
            okk &= h2 > 0.0  # lengths that cannot meet
            bad = ~okk
            np.copyto(h2, 1.0, where=bad)
            outk = _force(p, q, u, w, h2, neg_k, out[i:i + CHUNK])
            outk[bad] = 0.0
        return out.reshape(-1, T, 3), ok.reshape(-1, T)

    def _ratio(self, x: F64) -> tuple[F64, F64]:
        """p = R/R0 of (m, 3) readings as (3, m), and -k (3, m) in the same memory layout.

        A few taxels stay taxel-major (p is a transposed view); a chunk is
        copied pillar-major, so each pillar is contiguous.
        """
        m = x.shape[0]
        if m <= SMALL:
            return (x * self._inv_r0[:m]).T, self._neg_k[:m].T
        p = np.empty((3, m))
        np.multiply(x.T, self._inv_r0_t[:, :m], p)
        return p, self._neg_k_t[:, :m]


def _offset(p: F64, q: F64) -> tuple[F64, F64, F64]:
    """u = q_z/2 - q_x, w = q_z/2 - q_y and h² = p_z - u² - w², each (m,)."""
    hz = q[0] * _HALF
    u = hz - q[1]
    w = hz - q[2]
    h2 = u * u
    np.subtract(p[0], h2, h2)
    h2 -= w * w
    return u, w, h2


def _force(p: F64, q: F64, u: F64, w: F64, h2: F64, neg_k: F64, out: F64) -> F64:
    """Forces (m, 3) into out from decodable p, q, -k (3, m) and u, w, h² (m,); h2 is reused.

    The tensions are negated (c = -c_true, so C = -C_true): then
    (Fx, Fy, Fz) = (c_x - C·u, C·w - c_y, C·h).
    """
    c = np.sqrt(p)
    c += p  # (1 + s)·s = s + p
    np.divide(q, c, c)
    c *= neg_k
    cz, cx, cy = c[0], c[1], c[2]
    total = cz + cx
    total += cy
    fx, fy, fz = out[:, 0], out[:, 1], out[:, 2]
    np.multiply(total, u, fx)
    np.subtract(cx, fx, fx)
    np.multiply(total, w, fy)
    fy -= cy
    np.sqrt(h2, h2)
    np.multiply(total, h2, fz)
    return out


def tripod_force_from_ratio_change(
    q: F64, constants: SensorConstants
) -> tuple[F64, NDArray[np.bool_]]:
    """q (N, 3) of pillars (z, x, y) -> force (N, 3) as (Fx, Fy, Fz) and a valid mask (N,).

    Invalid taxels (non-finite q, strain past the limit, lengths that cannot
    meet) get 0 N and valid False. Computed as resistances with R0 = 1 ohm, so
    p = 1 + q is rounded once.
    """
    q = np.asarray(q, dtype=np.float64).reshape(-1, 3)
    n = q.shape[0]
    p = np.ones((-(-n // T) * T, 3))  # whole patches; the padding decodes to 0 N
    p[:n] += q
    force, ok = TripodInverse(constants, np.ones(3), math.inf).full(p.reshape(-1, T, 3))
    return force.reshape(-1, 3)[:n], ok.reshape(-1)[:n]
