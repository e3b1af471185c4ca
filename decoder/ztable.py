"""Fast exact z-only inverse: a tabulated cubic Hermite interpolant of Fz(q_z).

skin.normal solves the pure-normal-load tripod by Newton (exact, ~0.3 M taxels/s).
Fz(q) is smooth on its valid range, so it is tabulated once per set of constants
(values and 4th-order derivatives from the exact solver on a uniform grid) and
evaluated by a gathered Horner scheme. The interpolation error is below 1e-9 N
over the whole valid range (tests/decoder/test_ztable.py checks it against
skin.normal).

:class:`NormalInverse` applies the table to resistances for one R0: the grid
coordinate is one multiply-add of R, every step is a flat 1-D operation, and
batches go in chunks that stay in cache.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skin.constants import TAXELS_PER_PATCH as T
from skin.constants import SensorConstants
from skin.normal import normal_force_from_ratio_change

F64 = NDArray[np.float64]
KNOTS = 8192
CHUNK = 16380  # taxels per chunk (whole patches): the temporaries stay in cache
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
    """Horner coefficients of Fz on the uniform grid q = q_lo + t/inv_h, t in [0, KNOTS - 1].

    ``coef[j]`` holds c_j of every interval [k, k + 1]:
    Fz = ((c3*s + c2)*s + c1)*s + c0 with s = t - k. The last entry is the end
    knot itself (c0 = Fz(q_hi), the rest 0), so t = KNOTS - 1 needs no clamp.
    """

    q_lo: float
    q_hi: float
    inv_h: float
    coef: tuple[F64, F64, F64, F64]  # c0..c3, each (KNOTS,)

    @property
    def last(self) -> float:
        """The largest valid grid coordinate t."""
        return float(self.coef[0].shape[0] - 1)

    def interpolate(self, t: F64, out: F64) -> F64:
        """Fz at flat grid coordinates t, every one in [0, last] (the caller checks), into out."""
        c0, c1, c2, c3 = self.coef
        i = t.astype(np.intp)
        s = t - i
        np.multiply(c3[i], s, out=out)
        out += c2[i]
        out *= s
        out += c1[i]
        out *= s
        out += c0[i]
        return out

    def evaluate(self, q: F64) -> tuple[F64, NDArray[np.bool_]]:
        """Fz (N) and in-range mask for a flat float64 array of q = R/R0 - 1 (0 N outside)."""
        with np.errstate(over="ignore"):  # a huge q gives t = ±inf: invalid below
            t = np.asarray(q, dtype=np.float64).reshape(-1) * self.inv_h
            t -= self.q_lo * self.inv_h
        # NaN compares False: non-finite input lands here as invalid too.
        valid = (t >= 0.0) & (t <= self.last)
        np.copyto(t, 0.0, where=~valid)
        force = self.interpolate(t, np.empty(t.shape))
        force[~valid] = 0.0
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
    coef = np.zeros((4, KNOTS))
    coef[:, :-1] = (f0, m0, 3 * (f1 - f0) - 2 * m0 - m1, 2 * (f0 - f1) + m0 + m1)
    coef[0, -1] = f[-1]
    return NormalTable(q_lo=float(lo), q_hi=float(hi), inv_h=float(1.0 / h),
                       coef=(coef[0], coef[1], coef[2], coef[3]))


class NormalInverse:
    """Pillar-z resistances (n, 9, 1) in ohm -> Fz (n, 9), for one set of constants and R0.

    The grid coordinate is t = R·(inv_h/R0) - (1 + q_lo)·inv_h. A reading is
    decodable when 0 <= t <= last (NaN and ±inf are not) and, if the ADC's
    full scale lies inside the table, when R is below it. t is first computed
    divided by a power of two 2**k that brings inv_h/R0 to at most 1, so no
    reading, however large, overflows; multiplying by 2**k afterwards is exact.
    """

    def __init__(self, constants: SensorConstants, r0_ohm: F64, saturation_ohm: float) -> None:
        self.table = normal_table(constants)
        r0 = np.broadcast_to(np.asarray(r0_ohm, dtype=np.float64).reshape(-1), (T,))
        scale = self.table.inv_h / r0
        up = 2.0 ** max(0, math.ceil(math.log2(float(np.max(scale)))))
        # Per taxel, tiled over a chunk: every step below is a flat 1-D operation.
        self._scale = np.tile(scale / up, CHUNK // T)
        self._shift = np.array(-(1.0 + self.table.q_lo) * self.table.inv_h / up)
        self._last = self.table.last / up
        self._up = np.array(up)
        self._sat = saturation_ohm
        # 1e-9 of slack covers the rounding of t at the table's upper end.
        self._sat_reachable = bool(np.max(r0) * (1.0 + self.table.q_hi) * (1.0 + 1e-9)
                                   >= saturation_ohm)

    def _grid(self, x: F64) -> F64:
        """t / 2**k."""
        t = x * self._scale[:x.shape[0]]
        t += self._shift
        return t

    def fast(self, r: F64) -> F64 | None:
        """Fz (n, 9) if every reading is decodable, else None (nothing is masked here)."""
        x = r.reshape(-1)
        out = np.empty(x.shape)
        n = x.shape[0]
        if 0 < n <= CHUNK:
            ok = self._fast_chunk(x, out)
        else:
            ok = all(self._fast_chunk(x[i:i + CHUNK], out[i:i + CHUNK])
                     for i in range(0, n, CHUNK))
        return out.reshape(-1, T) if ok else None

    def _fast_chunk(self, x: F64, out: F64) -> bool:
        t = self._grid(x)
        # argmin/argmax stop at the first NaN, so a NaN fails these tests too.
        if not (t[t.argmin()] >= 0.0 and t[t.argmax()] <= self._last):
            return False
        if self._sat_reachable and not x[x.argmax()] < self._sat:
            return False
        t *= self._up
        self.table.interpolate(t, out)
        return True

    def full(self, r: F64) -> tuple[F64, NDArray[np.bool_]]:
        """Fz (n, 9) with 0 N where a reading is not decodable, and the decodable mask (n, 9)."""
        x = r.reshape(-1)
        out = np.empty(x.shape)
        ok = np.empty(x.shape, dtype=bool)
        for i in range(0, x.shape[0], CHUNK):
            xk, okk = x[i:i + CHUNK], ok[i:i + CHUNK]
            t = self._grid(xk)
            np.greater_equal(t, 0.0, out=okk)
            okk &= t <= self._last
            if self._sat_reachable:
                okk &= xk < self._sat
            bad = ~okk
            np.copyto(t, 0.0, where=bad)
            t *= self._up
            outk = self.table.interpolate(t, out[i:i + CHUNK])
            outk[bad] = 0.0
        return out.reshape(-1, T), ok.reshape(-1, T)
