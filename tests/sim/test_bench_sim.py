"""Speed benchmarks (pytest-benchmark); run with -n 0 --benchmark-enable to measure.

Figures: skin.benchmarks.sim.run_benchmark, printed by `skin bench sim`.
"""

from __future__ import annotations

from typing import Any

from sim import Simulator
from skin.benchmarks.sim import bench_scene, run_benchmark

STEPS = 2_000


def test_bench_forward_ideal(benchmark: Any) -> None:
    sim = Simulator(bench_scene(1, 1))
    frame = benchmark(sim.run, STEPS)
    assert frame.resistance_ohm.shape == (STEPS, 1, 9, 1)


def test_bench_passive_matrix(benchmark: Any) -> None:
    sim = Simulator(bench_scene(1, 1, mode="xyz", readout="passive_matrix"))
    frame = benchmark(sim.run, STEPS)
    assert frame.resistance_ohm.shape == (STEPS, 1, 9, 3)


def test_bench_64_patches_two_loaded(benchmark: Any) -> None:
    sim = Simulator(bench_scene(64, 2))
    frame = benchmark(sim.run, STEPS // 2)
    assert frame.resistance_ohm.shape == (STEPS // 2, 64, 9, 1)


def test_bench_2_patches(benchmark: Any) -> None:
    sim = Simulator(bench_scene(2, 2))
    benchmark(sim.run, STEPS // 2)


def test_run_benchmark_reports_every_figure() -> None:
    figures = run_benchmark(quick=True)
    assert set(figures) == {
        "ideal_taxel_samples_per_s", "ideal_noise_taxel_samples_per_s",
        "passive_matrix_patch_samples_per_s", "cost_ratio_64_vs_2_patches",
        "cost_ratio_64_vs_2_patches_noise",
    }
    assert all(v > 0 for v in figures.values())
