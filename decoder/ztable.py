"""Fast exact z-only inverse: a tabulated cubic Hermite interpolant of Fz(q_z).

skin.normal solves the pure-normal-load tripod by Newton (exact, ~0.3 M taxels/s).
Fz(q) is smooth on its valid range, so it is tabulated once per set of constants
(values and 4th-order derivatives from the exact solver on a uniform grid) and
evaluated by a gathered Horner scheme, chunked so the temporaries stay in cache.
The interpolation error is below 1e-9 N over the whole valid range
(tests/decoder/test_ztable.py checks it against skin.normal).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skin.constants import SensorConstants
from skin.normal import normal_force_from_ratio_change

F64 = NDArray[np.float64]
KNOTS = 8192
CHUNK = 16384
_STENCIL = 1e-5  # finite-difference step in q for the knot derivatives


def _valid_bound(constants: SensorConstants, inside: float, outside: float) -> float:
    """Bisect the edge of the valid range of the exact solver between two q values."""
    for _ in range(60):
        mid = 0.5 * (inside + outside)
        if normal_force_from_ratio_change(np.array([mid]), constants).valid[0]:
            inside = mid
        else:
            outside = mid
    return inside


@dataclass(frozen=True)
class NormalTable:
    """Per-interval Horner coefficients of Fz on a uniform grid q_lo + k*h."""

    q_lo: float
    q_hi: float
    inv_h: float
    coef: F64  # (KNOTS - 1, 4): Fz = ((c3*s + c2)*s + c1)*s + c0, s in [0, 1]

    def evaluate(self, q: F64) -> tuple[F64, NDArray[np.bool_]]:
        """Fz (N) and in-range mask for a flat float64 array of q = R/R0 - 1."""
        q = np.ascontiguousarray(q, dtype=np.float64).reshape(-1)
        n = q.shape[0]
        force = np.empty(n)
        valid = np.empty(n, dtype=bool)
        last = float(self.coef.shape[0])
        m = min(n, CHUNK)
        t = np.empty(m)
        s = np.empty(m)
        idx = np.empty(m, dtype=np.intp)
        c = np.empty((m, 4))
        offset = -self.q_lo * self.inv_h
        for start in range(0, n, CHUNK):
            stop = min(start + CHUNK, n)
            k = stop - start
            tk, sk, ik, ck, vk = t[:k], s[:k], idx[:k], c[:k], valid[start:stop]
            np.multiply(q[start:stop], self.inv_h, out=tk)
            tk += offset
            # NaN compares False: non-finite input lands here as invalid too.
            np.greater_equal(tk, 0.0, out=vk)
            vk &= tk <= last
            np.copyto(tk, 0.0, where=~vk)
            np.minimum(tk, last - 1e-9, out=tk)
            ik[...] = tk
            np.subtract(tk, ik, out=sk)
            np.take(self.coef, ik, axis=0, out=ck)
            out = force[start:stop]
            np.multiply(ck[:, 3], sk, out=out)
            out += ck[:, 2]
            out *= sk
            out += ck[:, 1]
            out *= sk
            out += ck[:, 0]
        return force, valid


@functools.lru_cache(maxsize=8)
def normal_table(constants: SensorConstants) -> NormalTable:
    """Build (once per constants) the interpolant of the exact pure-normal inverse."""
    e = constants.max_strain
    lo = _valid_bound(constants, 0.0, (1.0 - e) ** 2 - 1.0) + 4 * _STENCIL
    hi = _valid_bound(constants, 0.0, (1.0 + e) ** 2 - 1.0 + 1e-3) - 4 * _STENCIL
    q = np.linspace(lo, hi, KNOTS)
    h = q[1] - q[0]

    def force(x: F64) -> F64:
        result = normal_force_from_ratio_change(x, constants)
        if not np.all(result.valid):
            raise ArithmeticError("normal-force table left the exact solver's valid range")
        return result.force_N

    d = _STENCIL
    f = force(q)
    slope = (force(q - 2 * d) - 8 * force(q - d) + 8 * force(q + d) - force(q + 2 * d)) / (12 * d)
    f0, f1 = f[:-1], f[1:]
    m0, m1 = slope[:-1] * h, slope[1:] * h
    coef = np.stack((f0, m0, 3 * (f1 - f0) - 2 * m0 - m1, 2 * (f0 - f1) + m0 + m1), axis=1)
    return NormalTable(q_lo=float(lo), q_hi=float(hi), inv_h=float(1.0 / h),
                       coef=np.ascontiguousarray(coef))
