"""Determinism, independent random streams, chunking and the baseline cache."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from sim import Simulator, load_scene, scene_from_dict
from sim.effects.network import passive_matrix_resistance
from skin.constants import DEFAULT_CONSTANTS
from skin.errors import ConfigError

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels


def scene(patches: int, loaded: list[int], effects: dict[str, Any], mode: str = "xyz") -> Any:
    return scene_from_dict({
        "scene": {"name": "t", "mode": mode},
        "patches": [{"node_id": i + 1} for i in range(patches)],
        "loads": [{"kind": "uniform_random", "patches": loaded, "shear_max_N": 0.3}],
        "effects": effects,
    })


@pytest.mark.parametrize("name", ["hard", "grasp", "passive", "paper-noisy", "paper"])
def test_run_in_parts_equals_run_at_once(name: str) -> None:
    """Exactly, through the ADC; without it (``paper``) to a few ulp, because the tripod's
    Newton solve iterates a batch until its slowest sample converges."""
    s = load_scene(name)
    whole = Simulator(s).run(250)
    sim = Simulator(s)
    parts = [sim.run(k) for k in (1, 99, 0, 150)]
    for key in ("time_s", "resistance_ohm", "force_N"):
        joined = np.concatenate([getattr(p, key) for p in parts])
        if key == "resistance_ohm" and "noise" not in s.effects:
            np.testing.assert_allclose(getattr(whole, key), joined, rtol=4e-16, atol=0)
        else:
            np.testing.assert_array_equal(getattr(whole, key), joined)


def test_step_is_run_one() -> None:
    a, b = Simulator(load_scene("indenter")), Simulator(load_scene("indenter"))
    first = a.step()
    np.testing.assert_array_equal(first.resistance_ohm, b.run(1).resistance_ohm)
    assert a.step().time_s[0] == pytest.approx(0.01)


def test_seed_changes_draws_and_defaults_to_scene() -> None:
    s = load_scene("paper")
    same = Simulator(s, seed=s.seed).run(5).force_N
    np.testing.assert_array_equal(Simulator(s).run(5).force_N, same)
    assert not np.array_equal(Simulator(s, seed=1).run(5).force_N, same)


def test_listing_an_effect_leaves_other_streams_alone() -> None:
    plain = Simulator(scene(2, [1, 2], {})).run(50)
    noisy = Simulator(scene(2, [1, 2], {"noise": {}, "drift": {"walk_K_per_sqrt_s": 1.0}})).run(50)
    np.testing.assert_array_equal(plain.force_N, noisy.force_N)


@pytest.mark.parametrize("readout", ["ideal", "passive_matrix", "zero_potential"])
def test_idle_patches_equal_a_fresh_computation(readout: str) -> None:
    effects = {"elastic_crosstalk": {}, "hysteresis": {}, "readout": {"kind": readout}}
    frame = Simulator(scene(5, [2], effects)).run(40)
    r0 = np.broadcast_to(DEFAULT_CONSTANTS.nominal_resistance_ohm, (9, 3))
    if readout == "passive_matrix":
        fresh = passive_matrix_resistance(r0[None])[0]
    elif readout == "zero_potential":
        g_column = 3 / r0[0, 0] + 3 / r0[0, 2]
        leak = (1 + r0[0, 0] * np.where(np.arange(3) == 1, 3 / r0[0, 1], g_column)) / 1e4
        fresh = r0 * (1 + leak)
    else:
        fresh = r0
    for idle in (0, 2, 3, 4):
        expected = np.broadcast_to(fresh, (40, 9, 3))
        np.testing.assert_allclose(frame.resistance_ohm[:, idle], expected, rtol=1e-13)


def test_loaded_patch_output_does_not_depend_on_idle_patches() -> None:
    effects = {"elastic_crosstalk": {}, "readout": {"kind": "passive_matrix"}}
    small = Simulator(scene(2, [1, 2], effects)).run(30).resistance_ohm
    large = Simulator(scene(64, [1, 2], effects)).run(30).resistance_ohm
    np.testing.assert_array_equal(small, large[:, :2])


def test_noise_reaches_idle_patches() -> None:
    r = Simulator(scene(3, [1], {"noise": {}})).run(50).resistance_ohm
    assert np.unique(r[:, 2, 0, 0]).size > 5


def test_z_mode_reports_pillar_z() -> None:
    z = Simulator(scene(1, [1], {}, mode="z")).run(10).resistance_ohm
    xyz = Simulator(scene(1, [1], {})).run(10).resistance_ohm
    np.testing.assert_array_equal(z[..., 0], xyz[..., 0])
    assert z.shape[-1] == 1


def test_negative_steps_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match=r"^n: "):
        Simulator(load_scene("paper")).run(-1)


def test_combined_loads_over_strain() -> None:
    data = {
        "scene": {"name": "t"},
        "patches": [{"node_id": 1}],
        "loads": [{"kind": "uniform_random", "fz_min_N": 5.0, "fz_max_N": 7.0}] * 2,
    }
    sim = Simulator(scene_from_dict(data))
    with pytest.raises(ConfigError, match=r"^loads: the combined loads over-strain"):
        sim.run(5)
