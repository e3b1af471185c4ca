"""drift: temperature (a ramp plus a random walk, per patch) and creep (first-order strain lag).

Creep: an extra relative change c with dc/dt = (gain·q - c)/tau_s, integrated
exactly per step. Temperature: R scales by 1 + alpha·ΔT, ΔT(t) = ramp·t + a
random walk of ``walk_K_per_sqrt_s`` per √s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from sim.params import non_negative, positive

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class DriftParams:
    alpha_per_K: float = 0.002
    ramp_K_per_s: float = 0.01
    walk_K_per_sqrt_s: float = 0.0
    creep_tau_s: float = 5.0
    creep_gain: float = 0.05

    RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "alpha_per_K": (-1.0, 1.0), "ramp_K_per_s": (-100.0, 100.0),
        "walk_K_per_sqrt_s": (0.0, 100.0), "creep_tau_s": (0.0, 1e6), "creep_gain": (0.0, 1.0)}

    def check(self, where: str) -> None:
        positive(self.creep_tau_s, f"{where}.creep_tau_s")
        non_negative(self.creep_gain, f"{where}.creep_gain")
        non_negative(self.walk_K_per_sqrt_s, f"{where}.walk_K_per_sqrt_s")


class Drift:
    def __init__(
        self, p: DriftParams, patches: int, rate_hz: float, rng: np.random.Generator
    ) -> None:
        self.p, self.dt, self.rng = p, 1.0 / rate_hz, rng
        self.decay = 1.0 - math.exp(-self.dt / p.creep_tau_s)
        self.creep = np.zeros((patches, 9, 3))
        self.walk = np.zeros(patches)

    def apply(self, q: F64, time_s: F64) -> F64:
        """q (n, patches, 9, 3) -> drifted q, with creep state carried over steps."""
        p, n = self.p, q.shape[0]
        out = np.empty_like(q)
        if p.creep_gain > 0:
            c = self.creep
            for k in range(n):
                out[k] = q[k] + c
                c = c + (p.creep_gain * q[k] - c) * self.decay
            self.creep = c
        else:
            out[...] = q
        walk = np.zeros((n, self.walk.size))
        if p.walk_K_per_sqrt_s > 0 and n:
            steps = self.rng.standard_normal((n, self.walk.size))
            walk = self.walk + np.cumsum(steps, axis=0) * p.walk_K_per_sqrt_s * math.sqrt(self.dt)
            self.walk = walk[-1].copy()
        delta_k = p.ramp_K_per_s * time_s[:, None] + walk
        heat = (p.alpha_per_K * delta_k)[:, :, None, None]
        result: F64 = out + heat * (1.0 + out)  # (1 + q)(1 + αΔT) - 1
        return result
