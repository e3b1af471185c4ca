"""Simulator speed, as `skin bench sim` reports it.

* forward with ideal readout: taxel-samples/s of the paper's loads (z-only,
  crosstalk), without and with noise;
* passive_matrix: patch-samples/s (3-axis, every pillar of the network);
* scaling: the cost of a 64-patch scene with 2 loaded patches over a 2-patch
  scene, without and with noise (noise is drawn for every patch).
"""

from __future__ import annotations

import time
from typing import Any

from sim.scene import Scene, scene_from_dict
from sim.simulator import Simulator


def bench_scene(
    patches: int, loaded: int, *, mode: str = "z", readout: str = "ideal", noise: bool = False
) -> Scene:
    """A scene of ``patches`` patches, the first ``loaded`` under the paper's uniform load."""
    effects: dict[str, Any] = {"elastic_crosstalk": {}, "readout": {"kind": readout}}
    if noise:
        effects["noise"] = {}
    return scene_from_dict({
        "scene": {"name": f"bench-{patches}-{loaded}", "mode": mode},
        "patches": [{"node_id": i + 1} for i in range(patches)],
        "loads": [{"kind": "uniform_random", "patches": list(range(1, loaded + 1))}],
        "effects": effects,
    })


def seconds_per_run(scene: Scene, steps: int, repeats: int) -> float:
    """Best wall time of ``simulator.run(steps)`` over ``repeats`` runs (after one warm-up)."""
    sim = Simulator(scene)
    sim.run(min(steps, 16))
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        sim.run(steps)
        best = min(best, time.perf_counter() - start)
    return best


def run_benchmark(quick: bool = False) -> dict[str, float]:
    """Speed figures of the simulator on one core; ``quick`` for a fast, rougher run."""
    steps, repeats = (4_000, 3) if quick else (40_000, 5)
    ideal = seconds_per_run(bench_scene(1, 1), steps, repeats)
    ideal_noise = seconds_per_run(bench_scene(1, 1, noise=True), steps, repeats)
    passive = seconds_per_run(bench_scene(1, 1, mode="xyz", readout="passive_matrix"),
                              steps, repeats)
    ratio = {}
    for noise in (False, True):
        small = seconds_per_run(bench_scene(2, 2, noise=noise), steps // 2, repeats)
        large = seconds_per_run(bench_scene(64, 2, noise=noise), steps // 2, repeats)
        ratio[noise] = large / small
    return {
        "ideal_taxel_samples_per_s": 9 * steps / ideal,
        "ideal_noise_taxel_samples_per_s": 9 * steps / ideal_noise,
        "passive_matrix_patch_samples_per_s": steps / passive,
        "cost_ratio_64_vs_2_patches": ratio[False],
        "cost_ratio_64_vs_2_patches_noise": ratio[True],
    }


if __name__ == "__main__":
    for key, value in run_benchmark().items():
        print(f"{key}: {value:,.3f}")
