"""The stick-slip load: a pressed object whose tangential force is ramped past the friction
limit, so that it sticks, then slips, with its slip onset known as truth.

Each cycle of ``period_s`` (one centre and one direction drawn per cycle, like ``grasp``):

1. **stick** for ``ramp_s``: a sphere pressed at a fixed depth (the taxel under its centre
   carries ``fz_max_N``), and a tangential force on every loaded taxel ramped from 0 at a
   constant rate, reaching the friction limit μ·Fz (``friction``) at ``ramp_s``;
2. **slip** for ``slip_s``: the tangential force goes on rising past the limit (the drive
   keeps pulling), and the object slides: its centre moves at ``speed_m_per_s`` along the
   force. The first step at or past the limit is the slip onset (the truth);
3. **hold**: the tangential force released, the object pressed where it stopped (a stick
   phase: no slip);
4. **lift** for the last ``lift_s``: no force at all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sim.contact import sphere_fz
from sim.params import non_negative, positive
from sim.rng import stream
from skin.errors import ConfigError

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class StickSlipParams:
    """A press held while its tangential force is ramped past μ·Fz; see the module."""

    fz_max_N: float = 3.0
    radius_m: float = 0.04
    depth_m: float = 0.003
    friction: float = 0.5
    ramp_s: float = 0.3
    slip_s: float = 0.15
    lift_s: float = 0.25
    period_s: float = 1.0
    speed_m_per_s: float = 0.02

    def check(self, where: str) -> None:
        for name in ("fz_max_N", "radius_m", "depth_m", "friction", "ramp_s", "period_s"):
            positive(getattr(self, name), f"{where}.{name}")
        for name in ("slip_s", "lift_s", "speed_m_per_s"):
            non_negative(getattr(self, name), f"{where}.{name}")
        if self.ramp_s + self.slip_s + self.lift_s > self.period_s:
            raise ConfigError(f"{where}.period_s", f"{self.period_s:g} s is shorter than "
                              f"ramp_s + slip_s + lift_s = "
                              f"{self.ramp_s + self.slip_s + self.lift_s:g} s")

    @property
    def peak_ratio(self) -> float:
        """The largest tangential over normal force of a cycle (at the end of the slip)."""
        return self.friction * (self.ramp_s + self.slip_s) / self.ramp_s


class StickSlip:
    def __init__(self, p: StickSlipParams, patches: int, rate_hz: float, pitch_m: float,
                 seed: int, name: str) -> None:
        self.p, self.patches, self.rate, self.pitch = p, patches, rate_hz, pitch_m
        self.seed, self.name = seed, name
        self._cycles: dict[int, F64] = {}

    def _cycle(self, c: int) -> F64:
        """Per patch: centre (x, y) in half pitches, direction angle in turns."""
        if c not in self._cycles:
            self._cycles = {c: stream(self.seed, self.name, c).uniform(size=(self.patches, 3))}
        return self._cycles[c]

    def _phase(self, k0: int, n: int) -> tuple[F64, NDArray[np.int64], F64]:
        """Time into the cycle, the cycle, the draws of each step."""
        t = (k0 + np.arange(n)) / self.rate
        cycle = np.floor(t / self.p.period_s).astype(np.int64)
        draws = np.stack([self._cycle(int(c)) for c in cycle]) if n else \
            np.zeros((0, self.patches, 3))
        return t - cycle * self.p.period_s, cycle, draws

    def forces(self, k0: int, n: int) -> F64:
        p = self.p
        tc, _, draws = self._phase(k0, n)
        pressed = tc < p.period_s - p.lift_s
        ratio = np.where(tc < p.ramp_s + p.slip_s, p.friction * tc / p.ramp_s, 0.0)
        moved = p.speed_m_per_s * np.clip(tc - p.ramp_s, 0.0, p.slip_s)
        angle = 2.0 * np.pi * draws[..., 2]
        dx, dy = np.cos(angle), np.sin(angle)
        cx = (draws[..., 0] - 0.5) * self.pitch + moved[:, None] * dx
        cy = (draws[..., 1] - 0.5) * self.pitch + moved[:, None] * dy
        depth = np.where(pressed, p.depth_m, 0.0)[:, None] * np.ones((1, self.patches))
        fz = sphere_fz(cx, cy, depth, radius_m=p.radius_m, depth_max_m=p.depth_m,
                       fz_max_N=p.fz_max_N, pitch_m=self.pitch)
        shear = ratio[:, None, None] * fz
        return np.stack((shear * dx[..., None], shear * dy[..., None], fz), axis=-1)

    def slipping(self, k0: int, n: int) -> NDArray[np.bool_]:
        """(n, patches): the object slides (the slip phase)."""
        p = self.p
        tc, _, _ = self._phase(k0, n)
        # the step at or past the limit: the ramp reaches it at ramp_s exactly
        at_limit = tc >= p.ramp_s - 1e-9 / self.rate
        sliding = at_limit & (tc < p.ramp_s + p.slip_s)
        return np.repeat(sliding[:, None], self.patches, axis=1)

    def peak_forces(self) -> list[tuple[str, float, F64]]:
        p = self.p
        shear = p.peak_ratio * p.fz_max_N
        peaks = [("fz_max_N", p.fz_max_N, np.array([0.0, 0.0, p.fz_max_N]))]
        for a in range(8):
            angle = math.pi * a / 4
            force = np.array([shear * math.cos(angle), shear * math.sin(angle), p.fz_max_N])
            peaks.append(("friction", p.friction, force))
        return peaks
