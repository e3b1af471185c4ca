"""Fast exact 3-axis inverse: skin.tripod.force_from_ratio_change, specialised.

Same closed form (two length equations are linear in u once the first is
subtracted; the upper layer's height is then h = sqrt(h2)), reorganised for
speed: structure-of-arrays chunks that stay in cache, in-place operations, and
the strain test done on q directly (|e| <= e_max  <=>  (1-e_max)^2-1 <= q <= (1+e_max)^2-1).
Checked against skin.tripod to 1e-12 N by tests/decoder/test_analytic.py.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from skin.constants import SensorConstants

F64 = NDArray[np.float64]
CHUNK = 8192


def _tension_per_length(q: F64, stiffness_per_len: float, out: F64, tmp: F64) -> F64:
    """T/l' = (E·S/l)·(1 - 1/sqrt(1+q)) = (E·S/l)·q / ((1 + s)·s), s = sqrt(1+q)."""
    np.add(q, 1.0, out=tmp)
    np.sqrt(tmp, out=tmp)
    np.add(tmp, 1.0, out=out)
    out *= tmp
    np.divide(q, out, out=out)
    out *= stiffness_per_len
    return out


def tripod_force_from_ratio_change(
    q: F64, constants: SensorConstants
) -> tuple[F64, NDArray[np.bool_]]:
    """q (N, 3) of pillars (z, x, y) -> force (N, 3) as (Fx, Fy, Fz) and a valid mask (N,).

    Invalid taxels (non-finite q, strain past the limit, lengths that cannot
    meet) get 0 N and valid False.
    """
    q = np.asarray(q, dtype=np.float64)
    n = q.shape[0]
    force = np.empty((n, 3))
    valid = np.empty(n, dtype=bool)
    L = constants.length_m
    es = constants.axial_stiffness_N
    e = constants.max_strain
    q_lo, q_hi = (1.0 - e) ** 2 - 1.0, (1.0 + e) ** 2 - 1.0
    kz, kd = es / L, es / (math.sqrt(2.0) * L)
    m = min(n, CHUNK)
    qt = np.empty((3, m))
    ux, uy, h, cz, cx, cy, tmp = (np.empty(m) for _ in range(7))
    ok = np.empty(m, dtype=bool)
    for start in range(0, n, CHUNK):
        stop = min(start + CHUNK, n)
        k = stop - start
        qk = qt[:, :k]
        np.copyto(qk, q[start:stop].T)
        okk = ok[:k]
        np.all((qk >= q_lo) & (qk <= q_hi), axis=0, out=okk)
        qz, qx, qy = qk[0], qk[1], qk[2]
        if not np.all(okk):
            np.copyto(qk, 0.0, where=~okk)
        uxk, uyk, hk, tk = ux[:k], uy[:k], h[:k], tmp[:k]
        # ux = L/2 (qz - 2 qx), uy = L/2 (2 qy - qz), h2 = L^2 (1 + qz) - ux^2 - uy^2
        np.multiply(qx, -2.0, out=uxk)
        uxk += qz
        uxk *= 0.5 * L
        np.multiply(qy, 2.0, out=uyk)
        uyk -= qz
        uyk *= 0.5 * L
        np.multiply(qz, L * L, out=hk)
        hk += L * L
        np.multiply(uxk, uxk, out=tk)
        hk -= tk
        np.multiply(uyk, uyk, out=tk)
        hk -= tk
        okk &= hk > 0.0
        if not np.all(okk):
            bad = ~okk
            for arr in (qz, qx, qy, uxk, uyk):  # lengths that cannot meet
                np.copyto(arr, 0.0, where=bad)
            np.copyto(hk, L * L, where=bad)
        np.sqrt(hk, out=hk)
        czk = _tension_per_length(qz, kz, cz[:k], tk)
        cxk = _tension_per_length(qx, kd, cx[:k], tk)
        cyk = _tension_per_length(qy, kd, cy[:k], tk)
        np.add(czk, cxk, out=tk)
        tk += cyk
        out = force[start:stop]
        np.multiply(tk, uxk, out=out[:, 0])
        cxk *= L
        out[:, 0] -= cxk
        np.multiply(tk, uyk, out=out[:, 1])
        cyk *= L
        out[:, 1] += cyk
        np.multiply(tk, hk, out=out[:, 2])
        out[:, 2] *= -1.0
        valid[start:stop] = okk
    return force, valid
