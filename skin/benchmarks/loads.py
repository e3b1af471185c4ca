"""Load families for scene pairs: what presses on one patch, drawn sample by sample.

Each family returns true forces (n, 9, 3) from a generator. Some are the simulator's own
loads (``sim.loads``), drawn as the simulator draws them (``slide`` and ``grasp`` are time
series, so 1,000 samples of ``grasp`` are five squeeze cycles); the others are loads the
shipped scenes do not have: two spheres at once, a tilted flat plate and a press of one
fixed shape (loads with few degrees of freedom), a sphere pushed obliquely, and a
combination of a few fixed patterns.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sim.contact import sphere_fz
from sim.loads import LOAD_PARAMS, make_load
from skin.constants import DEFAULT_CONSTANTS
from skin.contact import taxel_xy

F64 = NDArray[np.float64]
PITCH_M = DEFAULT_CONSTANTS.taxel_pitch_m


@dataclass(frozen=True)
class Family:
    """A load family and its parameters: ``kind`` is one of ``KINDS``."""

    kind: str
    params: Mapping[str, Any] = field(default_factory=dict)

    def label(self) -> str:
        shown = ",".join(f"{k}={_short(v)}" for k, v in sorted(self.params.items()))
        return f"{self.kind}({shown})" if shown else self.kind

    def forces(self, n: int, seed: int) -> F64:
        return KINDS[self.kind](n, np.random.default_rng(_key(seed, self.label())),
                                dict(self.params), seed)


def _short(value: Any) -> str:
    return f"{value:.3g}" if isinstance(value, float) else str(value)


def _key(seed: int, label: str) -> list[int]:
    return [seed, zlib.crc32(label.encode())]


def _shear(fz: F64, rng: np.random.Generator, friction: float, per_sample: bool) -> F64:
    """(n, 9, 3) with Fz and a shear of ``friction`` x Fz in one random direction per
    sample (an oblique push) or per taxel."""
    n = fz.shape[0]
    angle = rng.uniform(0.0, 2.0 * np.pi, (n, 1) if per_sample else (n, 9))
    out = np.zeros((n, 9, 3))
    out[..., 0] = friction * fz * np.cos(angle)
    out[..., 1] = friction * fz * np.sin(angle)
    out[..., 2] = fz
    return out


def independent(n: int, rng: np.random.Generator, p: dict[str, Any], seed: int) -> F64:
    """The paper's protocol: each taxel's Fz ~ U[lo, hi] alone, shear ~ U[-s, s] alone."""
    out = np.zeros((n, 9, 3))
    out[..., 2] = rng.uniform(p.get("fz_min_N", 0.0), p.get("fz_max_N", 5.0), (n, 9))
    shear = p.get("shear_max_N", 0.0)
    if shear:
        out[..., :2] = rng.uniform(-shear, shear, (n, 9, 2))
    return out


def _spheres(n: int, rng: np.random.Generator, p: dict[str, Any], count: int) -> F64:
    half = 1.5 * PITCH_M
    fz = np.zeros((n, 9))
    for _ in range(count):
        draw = rng.uniform(size=(n, 3))
        fz += sphere_fz((2 * draw[:, 0] - 1) * half, (2 * draw[:, 1] - 1) * half,
                        draw[:, 2] * p.get("depth_max_m", 0.003),
                        radius_m=p.get("radius_m", 0.04),
                        depth_max_m=p.get("depth_max_m", 0.003),
                        fz_max_N=p.get("fz_max_N", 4.0), pitch_m=PITCH_M)
    return _shear(fz, rng, p.get("friction", 0.0), per_sample=True)


def spheres(n: int, rng: np.random.Generator, p: dict[str, Any], seed: int) -> F64:
    """``count`` spheres (1 by default) at random points and depths, their forces added; an
    oblique push adds ``friction`` x Fz of shear in one random direction per sample."""
    return _spheres(n, rng, p, int(p.get("count", 1)))


def plate(n: int, rng: np.random.Generator, p: dict[str, Any], seed: int) -> F64:
    """A flat plate pressed with a random tilt: Fz = fz_max x clip(d + a·x + b·y, 0, 1), three
    degrees of freedom (``tilt`` 0: one, all taxels alike)."""
    x, y = taxel_xy(PITCH_M).T
    tilt = p.get("tilt", 0.5)
    d = rng.uniform(0.0, 1.0, (n, 1))
    a, b = (rng.uniform(-tilt, tilt, (n, 1)) / PITCH_M for _ in range(2))
    fz = p.get("fz_max_N", 4.0) * np.clip(d + a * x + b * y, 0.0, 1.0)
    return _shear(fz, rng, p.get("friction", 0.0), per_sample=True)


def patterns(n: int, rng: np.random.Generator, p: dict[str, Any], seed: int) -> F64:
    """``k`` fixed load shapes (drawn once from ``shapes_seed``), each sample a random
    non-negative mix of them scaled to at most ``fz_max_N``: k degrees of freedom."""
    k = int(p.get("k", 2))
    shapes = np.random.default_rng(int(p.get("shapes_seed", 0))).uniform(0.0, 1.0, (k, 9))
    weights = rng.uniform(0.0, 1.0, (n, k))
    fz = weights @ shapes
    fz *= p.get("fz_max_N", 4.0) / max(float(shapes.sum(axis=0).max()), 1e-12)
    return _shear(fz, rng, p.get("friction", 0.0), per_sample=True)


def simulated(kind: str) -> Callable[[int, np.random.Generator, dict[str, Any], int], F64]:
    """The simulator's load ``kind`` with these parameters, from time step 0."""

    def draw(n: int, rng: np.random.Generator, p: dict[str, Any], seed: int) -> F64:
        params = LOAD_PARAMS[kind](**p)
        load = make_load(kind, params, 1, rate_hz=100.0, pitch_m=PITCH_M, seed=seed,
                         name="loads[0]")
        out: F64 = load.forces(0, n)[:, 0]
        return out

    return draw


KINDS: dict[str, Callable[[int, np.random.Generator, dict[str, Any], int], F64]] = {
    "independent": independent,
    "spheres": spheres,
    "plate": plate,
    "patterns": patterns,
    "slide": simulated("slide"),
    "grasp": simulated("grasp"),
}
"""Every load family by name."""
