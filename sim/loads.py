"""Loads: what presses on the patches, step by step.

Every load returns the true force (Fx, Fy, Fz) on its patches for time steps
``k0 .. k0+n-1`` as an array (n, patches, 9, 3). Random loads draw from their
own stream, sequentially, so run(a) then run(b) equals run(a + b).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Protocol

import numpy as np
from numpy.typing import NDArray

from sim.contact import sphere_fz
from sim.params import non_negative, positive
from sim.rng import stream
from sim.stickslip import StickSlip, StickSlipParams
from skin.contact import taxel_xy

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class UniformRandomParams:
    """The paper's protocol: every taxel's Fz ~ U[fz_min_N, fz_max_N], independently."""

    fz_max_N: float = 5.0
    fz_min_N: float = 0.0
    shear_max_N: float = 0.0

    RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "fz_max_N": (0.0, 1e3), "fz_min_N": (0.0, 1e3), "shear_max_N": (0.0, 1e3)}

    def check(self, where: str) -> None:
        non_negative(self.fz_min_N, f"{where}.fz_min_N")
        positive(self.fz_max_N - self.fz_min_N, f"{where}.fz_max_N - fz_min_N")
        non_negative(self.shear_max_N, f"{where}.shear_max_N")


@dataclass(frozen=True)
class IndenterParams:
    """A sphere pressed at a random point of the patch to a random depth, every step."""

    fz_max_N: float = 4.0
    radius_m: float = 0.04
    depth_max_m: float = 0.003

    RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "fz_max_N": (0.0, 1e3), "radius_m": (1e-6, 1.0), "depth_max_m": (1e-9, 0.1)}

    def check(self, where: str) -> None:
        for name in ("fz_max_N", "radius_m", "depth_max_m"):
            positive(getattr(self, name), f"{where}.{name}")


@dataclass(frozen=True)
class SlideParams:
    """A sphere at full depth sliding across the patch, friction giving shear along the motion."""

    fz_max_N: float = 3.0
    radius_m: float = 0.04
    depth_max_m: float = 0.003
    speed_m_per_s: float = 0.05
    angle_deg: float = 0.0
    offset_m: float = 0.0
    friction: float = 0.3

    RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "fz_max_N": (0.0, 1e3), "radius_m": (1e-6, 1.0), "depth_max_m": (1e-9, 0.1),
        "speed_m_per_s": (0.0, 100.0), "angle_deg": (-360.0, 360.0), "offset_m": (-1.0, 1.0),
        "friction": (0.0, 10.0)}

    def check(self, where: str) -> None:
        for name in ("fz_max_N", "radius_m", "depth_max_m", "speed_m_per_s"):
            positive(getattr(self, name), f"{where}.{name}")
        non_negative(self.friction, f"{where}.friction")


@dataclass(frozen=True)
class GraspParams:
    """Squeeze-and-release cycles; each cycle draws its amplitude, centre and shear."""

    fz_max_N: float = 3.0
    shear_max_N: float = 0.5
    period_s: float = 2.0
    width_m: float = 0.02

    RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "fz_max_N": (0.0, 1e3), "shear_max_N": (0.0, 1e3), "period_s": (1e-3, 1e6),
        "width_m": (1e-6, 1.0)}

    def check(self, where: str) -> None:
        for name in ("fz_max_N", "period_s", "width_m"):
            positive(getattr(self, name), f"{where}.{name}")
        non_negative(self.shear_max_N, f"{where}.shear_max_N")


@dataclass(frozen=True)
class IdleParams:
    """No force."""

    def check(self, where: str) -> None:
        return None


LOAD_PARAMS: dict[str, type] = {
    "uniform_random": UniformRandomParams,
    "indenter": IndenterParams,
    "slide": SlideParams,
    "grasp": GraspParams,
    "idle": IdleParams,
    "stick_slip": StickSlipParams,
}


class Load(Protocol):
    def forces(self, k0: int, n: int) -> F64: ...

    def slipping(self, k0: int, n: int) -> NDArray[np.bool_]:
        """(n, patches): the truth of slip, the load sliding over the patch."""
        ...

    def peak_forces(self) -> list[tuple[str, float, F64]]:
        """(field, its value, the largest force vector it can put on one taxel)."""
        ...


class UniformRandom:
    def __init__(self, p: UniformRandomParams, patches: int, rng: np.random.Generator) -> None:
        self.p, self.patches, self.rng = p, patches, rng

    def forces(self, k0: int, n: int) -> F64:
        out = np.zeros((n, self.patches, 9, 3))
        p = self.p
        out[..., 2] = self.rng.uniform(p.fz_min_N, p.fz_max_N, size=(n, self.patches, 9))
        if p.shear_max_N > 0:
            s = p.shear_max_N
            out[..., :2] = self.rng.uniform(-s, s, size=(n, self.patches, 9, 2))
        return out

    def slipping(self, k0: int, n: int) -> NDArray[np.bool_]:
        return np.zeros((n, self.patches), dtype=bool)

    def peak_forces(self) -> list[tuple[str, float, F64]]:
        p = self.p
        peaks = [("fz_max_N", p.fz_max_N, np.array([0.0, 0.0, p.fz_max_N]))]
        for sx, sy in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
            force = np.array([sx * p.shear_max_N, sy * p.shear_max_N, p.fz_max_N])
            peaks.append(("shear_max_N", p.shear_max_N, force))
        return peaks


class Indenter:
    def __init__(
        self, p: IndenterParams, patches: int, rng: np.random.Generator, pitch_m: float
    ) -> None:
        self.p, self.patches, self.rng, self.pitch = p, patches, rng, pitch_m

    def forces(self, k0: int, n: int) -> F64:
        p, half = self.p, 1.5 * self.pitch
        draw = self.rng.uniform(size=(n, self.patches, 3))
        out = np.zeros((n, self.patches, 9, 3))
        out[..., 2] = sphere_fz(
            (2.0 * draw[..., 0] - 1.0) * half, (2.0 * draw[..., 1] - 1.0) * half,
            draw[..., 2] * p.depth_max_m, radius_m=p.radius_m, depth_max_m=p.depth_max_m,
            fz_max_N=p.fz_max_N, pitch_m=self.pitch,
        )
        return out

    def slipping(self, k0: int, n: int) -> NDArray[np.bool_]:
        return np.zeros((n, self.patches), dtype=bool)

    def peak_forces(self) -> list[tuple[str, float, F64]]:
        return [("fz_max_N", self.p.fz_max_N, np.array([0.0, 0.0, self.p.fz_max_N]))]


class Slide:
    def __init__(self, p: SlideParams, patches: int, rate_hz: float, pitch_m: float) -> None:
        self.p, self.patches, self.rate, self.pitch = p, patches, rate_hz, pitch_m
        contact = math.sqrt(2.0 * p.radius_m * p.depth_max_m)
        self.span = 3.0 * pitch_m + 2.0 * contact
        angle = math.radians(p.angle_deg)
        self.direction = (math.cos(angle), math.sin(angle))

    def forces(self, k0: int, n: int) -> F64:
        p, (dx, dy) = self.p, self.direction
        t = (k0 + np.arange(n)) / self.rate
        s = np.mod(p.speed_m_per_s * t, self.span) - 0.5 * self.span
        cx, cy = s * dx - p.offset_m * dy, s * dy + p.offset_m * dx
        fz = sphere_fz(
            cx, cy, np.full(n, p.depth_max_m), radius_m=p.radius_m, depth_max_m=p.depth_max_m,
            fz_max_N=p.fz_max_N, pitch_m=self.pitch,
        )
        one = np.stack((p.friction * dx * fz, p.friction * dy * fz, fz), axis=-1)
        return np.repeat(one[:, None], self.patches, axis=1)

    def slipping(self, k0: int, n: int) -> NDArray[np.bool_]:
        """The sphere slides whenever it touches the patch."""
        touching = self.forces(k0, n)[:, 0, :, 2].sum(axis=1) > 0
        return np.repeat(touching[:, None], self.patches, axis=1)

    def peak_forces(self) -> list[tuple[str, float, F64]]:
        p, (dx, dy) = self.p, self.direction
        shear = p.friction * p.fz_max_N
        return [
            ("fz_max_N", p.fz_max_N, np.array([0.0, 0.0, p.fz_max_N])),
            ("friction", p.friction, np.array([shear * dx, shear * dy, p.fz_max_N])),
        ]


class Grasp:
    def __init__(
        self, p: GraspParams, patches: int, rate_hz: float, pitch_m: float, seed: int, name: str
    ) -> None:
        self.p, self.patches, self.rate, self.pitch = p, patches, rate_hz, pitch_m
        self.seed, self.name = seed, name
        self._cycles: dict[int, F64] = {}

    def _cycle(self, c: int) -> F64:
        """Per patch: amplitude fraction, centre (x, y) in pitches, shear fraction, angle."""
        if c not in self._cycles:
            self._cycles = {c: stream(self.seed, self.name, c).uniform(size=(self.patches, 5))}
        return self._cycles[c]

    def forces(self, k0: int, n: int) -> F64:
        p = self.p
        t = (k0 + np.arange(n)) / self.rate
        cycle = np.floor(t / p.period_s).astype(np.int64)
        draws = np.stack([self._cycle(int(c)) for c in cycle]) if n else np.zeros((0, 1, 5))
        envelope = 0.5 * (1.0 - np.cos(2.0 * np.pi * t / p.period_s))
        x, y = taxel_xy(self.pitch).T
        cx = (2.0 * draws[..., 1] - 1.0) * self.pitch
        cy = (2.0 * draws[..., 2] - 1.0) * self.pitch
        r2 = (cx[..., None] - x) ** 2 + (cy[..., None] - y) ** 2
        shape = np.exp(-r2 / (2.0 * p.width_m**2)) * envelope[:, None, None]
        fz = (0.5 + 0.5 * draws[..., 0])[..., None] * p.fz_max_N * shape
        shear = (draws[..., 3] * p.shear_max_N)[..., None] * shape
        angle = (2.0 * np.pi * draws[..., 4])[..., None]
        return np.stack((shear * np.cos(angle), shear * np.sin(angle), fz), axis=-1)

    def slipping(self, k0: int, n: int) -> NDArray[np.bool_]:
        return np.zeros((n, self.patches), dtype=bool)

    def peak_forces(self) -> list[tuple[str, float, F64]]:
        p = self.p
        peaks = [("fz_max_N", p.fz_max_N, np.array([0.0, 0.0, p.fz_max_N]))]
        for sx, sy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            force = np.array([sx * p.shear_max_N, sy * p.shear_max_N, p.fz_max_N])
            peaks.append(("shear_max_N", p.shear_max_N, force))
        return peaks


class Idle:
    def __init__(self, patches: int) -> None:
        self.patches = patches

    def forces(self, k0: int, n: int) -> F64:
        return np.zeros((n, self.patches, 9, 3))

    def slipping(self, k0: int, n: int) -> NDArray[np.bool_]:
        return np.zeros((n, self.patches), dtype=bool)

    def peak_forces(self) -> list[tuple[str, float, F64]]:
        return []


def make_load(
    kind: str, params: object, patches: int, *, rate_hz: float, pitch_m: float, seed: int,
    name: str,
) -> Load:
    """The load ``kind`` acting on ``patches`` patches; ``name`` keys its random stream."""
    if isinstance(params, UniformRandomParams):
        return UniformRandom(params, patches, stream(seed, name))
    if isinstance(params, IndenterParams):
        return Indenter(params, patches, stream(seed, name), pitch_m)
    if isinstance(params, SlideParams):
        return Slide(params, patches, rate_hz, pitch_m)
    if isinstance(params, GraspParams):
        return Grasp(params, patches, rate_hz, pitch_m, seed, name)
    if isinstance(params, IdleParams):
        return Idle(patches)
    if isinstance(params, StickSlipParams):
        return StickSlip(params, patches, rate_hz, pitch_m, seed, name)
    raise TypeError(f"no load for {kind!r} parameters {params!r}")
