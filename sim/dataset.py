"""Datasets from scenes: the paper's protocol, or any other scene."""

from __future__ import annotations

import numpy as np

from sim.scene import Scene, load_scene
from sim.simulator import Simulator
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.dataset import Dataset
from skin.errors import ConfigError
from skin.inputs.budget import require_memory

_CHUNK = 4096  # time steps per batch: bounds the temporaries, not the result


def generate_dataset(
    scene: Scene | str, n: int, seed: int, *, constants: SensorConstants = DEFAULT_CONSTANTS
) -> Dataset:
    """``n`` samples of ``scene`` (a Scene, a shipped name or a path) with ``seed``."""
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ConfigError("n", f"must be a positive number of samples, got {n!r}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ConfigError("seed", f"must be a non-negative integer, got {seed!r}")
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    per_sample = len(scene.patches) * 9 * (scene.pillars + 3) * 8
    # the batches, then the arrays they are joined into
    require_memory(2 * n * per_sample, f"{n} samples of scene {scene.name!r}", "n")
    sim = Simulator(scene, seed=int(seed), constants=constants)
    frames = [sim.run(min(_CHUNK, n - k)) for k in range(0, n, _CHUNK)]
    resistance = np.concatenate([f.resistance_ohm for f in frames])
    force = np.concatenate([f.force_N for f in frames])
    meta = {
        "scene": scene.to_dict(),
        "seed": int(seed),
        "effects": scene.listed_effects(),
        "constants": constants.to_dict(),
        "mode": scene.mode,
    }
    return Dataset(resistance_ohm=resistance, force_N=force, meta=meta)
