"""Scene pairs: a decoder trained on one scene, tested at home and on another scene.

A scene here is a load family (:mod:`skin.benchmarks.loads`) read by one patch: the rubber's
crosstalk (shared by both scenes of a pair: it is the same patch), then the exact tripod
model, then the reading (Gaussian read noise and the 16-bit ADC, or the ADC alone, or exact
floats), each scene with its own. ``random_pair`` draws pairs the project does not ship, for
checks that must hold on scenes nobody chose; ``PAIRS`` are fixed ones for ``skin bench
cross``.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sim.effects.crosstalk import crosstalk_matrix
from sim.effects.noise import quantise
from skin.benchmarks.loads import Family
from skin.constants import DEFAULT_CONSTANTS
from skin.tripod import resistance_from_force

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Reading:
    """How a patch reports: read noise (a fraction of R0, then the ADC), the ADC alone
    (``quantised`` without noise), or exact floats."""

    noise_rel: float = 0.0005
    quantised: bool = True

    def label(self) -> str:
        if self.noise_rel > 0:
            return f"noise {100 * self.noise_rel:.3g}%"
        return "ADC only" if self.quantised else "exact"


@dataclass(frozen=True)
class Scene:
    family: Family
    reading: Reading = Reading()

    def label(self) -> str:
        return f"{self.family.label()} [{self.reading.label()}]"


@dataclass(frozen=True)
class ScenePair:
    """Train on ``train``, test on another seed of ``train`` (home) and on ``test`` (away)."""

    name: str
    mode: str
    train: Scene
    test: Scene
    coupling: float = 0.05
    diagonal_coupling: float = 0.02

    @property
    def pillars(self) -> int:
        return 1 if self.mode == "z" else 3

    def crosstalk(self) -> F64:
        return crosstalk_matrix(self.coupling, self.diagonal_coupling)


@dataclass(frozen=True)
class PairData:
    """Resistances (n, 9, P) and true forces (n, 9, 3) of the three sets, and M."""

    train: tuple[F64, F64]
    home: tuple[F64, F64]
    away: tuple[F64, F64]
    crosstalk: F64


def read(force: F64, pair: ScenePair, reading: Reading, seed: int) -> F64:
    """What the pair's patch reports under ``force`` (n, 9, 3): (n, 9, P) in ohm."""
    effective = np.einsum("kj,njc->nkc", pair.crosstalk(), force)
    if pair.mode == "z":
        effective[..., :2] = 0.0
    r: F64 = resistance_from_force(effective)[..., : pair.pillars]
    if reading.noise_rel > 0:
        rng = np.random.default_rng([seed, zlib.crc32(b"noise")])
        r0 = DEFAULT_CONSTANTS.nominal_resistance_ohm[: pair.pillars]
        r = r + rng.standard_normal(r.shape) * (reading.noise_rel * r0)
    if reading.quantised or reading.noise_rel > 0:
        r = quantise(r, DEFAULT_CONSTANTS)
    return r


def _side(pair: ScenePair, scene: Scene, n: int, seed: int) -> tuple[F64, F64]:
    force = scene.family.forces(n, seed)
    if pair.mode == "z":
        force[..., :2] = 0.0
    return read(force, pair, scene.reading, seed), force


def pair_data(pair: ScenePair, n_train: int, n_test: int, seed: int = 1) -> PairData:
    """``n_train`` samples of the training scene (``seed``), ``n_test`` of it and of the test
    scene (``seed + 1``)."""
    return PairData(_side(pair, pair.train, n_train, seed),
                    _side(pair, pair.train, n_test, seed + 1),
                    _side(pair, pair.test, n_test, seed + 1), pair.crosstalk())


READINGS = (Reading(0.0, False), Reading(0.0, True), Reading(0.00025), Reading(0.0005),
            Reading(0.001))
"""Exact floats, the ADC alone, and read noise of 0.025 %, 0.05 % and 0.1 % of R0."""


def random_family(rng: np.random.Generator, mode: str) -> Family:
    """A load family with parameters drawn from ranges the sensor can take (no pillar past
    its strain limit with the strongest crosstalk drawn)."""
    shear = mode == "xyz"
    kind = str(rng.choice(["independent", "spheres", "spheres", "plate", "patterns", "slide",
                           "grasp"]))
    u = rng.uniform
    friction = float(u(0.0, 0.3)) if shear and u() < 0.6 else 0.0
    if kind == "independent":
        params = {"fz_max_N": float(u(2.0, 5.0)), "fz_min_N": float(u(0.0, 1.0)) * (u() < 0.3),
                  "shear_max_N": float(u(0.1, 0.5)) if shear and u() < 0.6 else 0.0}
    elif kind == "spheres":
        count = int(rng.integers(1, 3))
        params = {"count": count, "radius_m": float(u(0.01, 0.08)),
                  "depth_max_m": float(u(0.002, 0.004)),
                  "fz_max_N": float(u(2.0, 4.0)) / count, "friction": friction}
    elif kind == "plate":
        params = {"tilt": float(u(0.0, 1.0)), "fz_max_N": float(u(2.0, 4.5)),
                  "friction": friction}
    elif kind == "patterns":
        params = {"k": int(rng.integers(1, 5)), "shapes_seed": int(rng.integers(0, 1000)),
                  "fz_max_N": float(u(2.0, 4.5)), "friction": friction}
    elif kind == "slide":
        params = {"fz_max_N": float(u(2.0, 4.0)), "radius_m": float(u(0.02, 0.06)),
                  "angle_deg": float(u(0.0, 360.0)), "offset_m": float(u(-0.01, 0.01)),
                  "friction": float(u(0.0, 0.4)) if shear else 0.0}
    else:
        params = {"fz_max_N": float(u(2.0, 4.0)), "shear_max_N": float(u(0.0, 0.6)) * shear,
                  "width_m": float(u(0.01, 0.03)), "period_s": float(u(1.0, 3.0))}
    return Family(kind, {k: v for k, v in params.items() if v != 0.0 or k == "fz_min_N"})


def random_pair(seed: int) -> ScenePair:
    """A scene pair drawn from ``seed``: a mode, one patch's crosstalk, two load families
    (possibly the same kind with other parameters) and each scene's reading."""
    rng = np.random.default_rng([seed, zlib.crc32(b"pair")])
    mode = "z" if rng.uniform() < 0.5 else "xyz"
    train, test = random_family(rng, mode), random_family(rng, mode)
    readings = [READINGS[int(i)] for i in rng.integers(0, len(READINGS), 2)]
    if rng.uniform() < 0.5:
        readings[1] = readings[0]
    return ScenePair(f"random-{seed}", mode, Scene(train, readings[0]),
                     Scene(test, readings[1]), float(rng.uniform(0.02, 0.08)),
                     float(rng.uniform(0.0, 0.03)))


NOISE, FINE, COARSE = Reading(0.0005), Reading(0.00025), Reading(0.001)
ADC = Reading(0.0, True)
SPHERE = Family("spheres", {"radius_m": 0.04, "fz_max_N": 4.0})
PAIRS = (
    ScenePair("two spheres -> independent", "z",
              Scene(Family("spheres", {"count": 2, "fz_max_N": 2.5}), NOISE),
              Scene(Family("independent", {"fz_max_N": 5.0}), NOISE)),
    ScenePair("tilted plate -> independent", "z", Scene(Family("plate", {"tilt": 0.5}), NOISE),
              Scene(Family("independent", {"fz_max_N": 5.0}), NOISE)),
    ScenePair("3 patterns -> sphere", "z",
              Scene(Family("patterns", {"k": 3, "shapes_seed": 1}), NOISE), Scene(SPHERE, NOISE)),
    ScenePair("independent -> sphere, ADC only", "z", Scene(Family("independent"), ADC),
              Scene(SPHERE, ADC)),
    ScenePair("sphere 40 mm -> 15 mm", "z", Scene(SPHERE, NOISE),
              Scene(Family("spheres", {"radius_m": 0.015, "fz_max_N": 3.0}), NOISE)),
    ScenePair("sphere -> two spheres, ADC only", "z", Scene(SPHERE, ADC),
              Scene(Family("spheres", {"count": 2, "fz_max_N": 2.0}), ADC)),
    ScenePair("sphere (0.1 % noise) -> slide", "xyz", Scene(SPHERE, COARSE),
              Scene(Family("slide", {"angle_deg": 30.0}), NOISE)),
    ScenePair("sphere -> oblique sphere", "xyz", Scene(SPHERE, NOISE),
              Scene(Family("spheres", {"friction": 0.2, "fz_max_N": 3.0}), NOISE)),
    ScenePair("two spheres -> tilted plate, ADC only", "xyz",
              Scene(Family("spheres", {"count": 2, "fz_max_N": 2.0}), ADC),
              Scene(Family("plate", {"tilt": 0.5, "fz_max_N": 3.0}), ADC)),
    ScenePair("independent with shear -> slide", "xyz",
              Scene(Family("independent", {"shear_max_N": 0.4}), FINE),
              Scene(Family("slide", {"angle_deg": 120.0, "friction": 0.2}), FINE)),
    ScenePair("grasp -> sphere", "xyz", Scene(Family("grasp"), NOISE), Scene(SPHERE, NOISE)),
    ScenePair("slide -> sphere 20 mm, ADC only", "xyz",
              Scene(Family("slide", {"angle_deg": 60.0}), ADC),
              Scene(Family("spheres", {"radius_m": 0.02, "fz_max_N": 3.0}), ADC)),
)
"""``skin bench cross``'s scene pairs beyond the shipped scenes: a second indenter (another
sphere radius), two indenters at once, loads with few degrees of freedom (a tilted plate,
three fixed shapes), an oblique press, quantised readings (the ADC alone), three noise
levels, both modes."""
