"""Crosstalk, noise and ADC, hysteresis, drift and faults."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from sim import Simulator, scene_from_dict
from sim.effects.crosstalk import crosstalk_matrix
from sim.effects.drift import Drift, DriftParams
from sim.effects.hysteresis import Hysteresis, HysteresisParams
from sim.effects.noise import quantise
from sim.rng import stream
from skin.constants import DEFAULT_CONSTANTS

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels

LSB = DEFAULT_CONSTANTS.resistance_lsb_ohm
FULL = DEFAULT_CONSTANTS.adc_full_scale_code * LSB
R0 = DEFAULT_CONSTANTS.nominal_resistance_ohm


def idle_scene(effects: dict[str, Any], mode: str = "xyz", loads: Any = ()) -> Any:
    return scene_from_dict({
        "scene": {"name": "t", "mode": mode},
        "patches": [{"node_id": 1}, {"node_id": 2}],
        "loads": list(loads),
        "effects": effects,
    })


def test_crosstalk_edge_gathers_less_than_centre() -> None:
    m = crosstalk_matrix(0.05, 0.02)
    np.testing.assert_array_equal(m, m.T)
    sums = m.sum(axis=1).reshape(3, 3)
    assert sums[1, 1] == pytest.approx(1 + 4 * 0.05 + 4 * 0.02)
    assert sums[0, 1] == pytest.approx(1 + 3 * 0.05 + 2 * 0.02)
    assert sums[0, 0] == pytest.approx(1 + 2 * 0.05 + 1 * 0.02)
    assert sums[0, 0] < sums[0, 1] < sums[1, 1]


def test_crosstalk_changes_resistance_not_reported_force() -> None:
    loads = [{"kind": "uniform_random"}]
    plain = Simulator(idle_scene({}, loads=loads)).run(20)
    spread = Simulator(idle_scene({"elastic_crosstalk": {}}, loads=loads)).run(20)
    np.testing.assert_array_equal(plain.force_N, spread.force_N)
    assert np.all(spread.resistance_ohm[..., 0] < plain.resistance_ohm[..., 0])


def test_noise_statistics_and_quantisation() -> None:
    frame = Simulator(idle_scene({"noise": {"sigma_rel": 0.01}})).run(2000)
    r = frame.resistance_ohm
    codes = r / LSB
    np.testing.assert_allclose(codes, np.rint(codes), atol=1e-6)
    for p in range(3):
        assert r[..., p].mean() == pytest.approx(R0[p], rel=1e-3)
        assert r[..., p].std() == pytest.approx(0.01 * R0[p], rel=0.05)


def test_noiseless_adc_rounds_and_saturates() -> None:
    frame = Simulator(idle_scene({"noise": {"sigma_rel": 0.0}})).run(2)
    np.testing.assert_array_equal(frame.resistance_ohm[0, 0, 0], np.rint(R0 / LSB) * LSB)
    r = np.array([1e9, np.inf, -5.0, 1000.02])
    np.testing.assert_array_equal(quantise(r, DEFAULT_CONSTANTS), [FULL, FULL, 0.0, 1000.0])


def test_hysteresis_loop_width() -> None:
    h = Hysteresis(HysteresisParams(width=0.01), (1,))
    up = np.linspace(0.0, -0.1, 101)
    x = np.concatenate([up, up[::-1]])[:, None]
    y = h.apply(x)[:, 0]
    loading, unloading = y[:101], y[101:][::-1]
    mid = 50  # x = -0.05 on both branches
    assert unloading[mid] - loading[mid] == pytest.approx(-0.01)
    assert loading[mid] == pytest.approx(-0.045)


def test_hysteresis_state_carries_over_runs() -> None:
    loads = [{"kind": "uniform_random"}]
    scene = idle_scene({"hysteresis": {}}, loads=loads)
    whole = Simulator(scene).run(30).resistance_ohm
    sim = Simulator(scene)
    parts = np.concatenate([sim.run(11).resistance_ohm, sim.run(19).resistance_ohm])
    np.testing.assert_array_equal(whole, parts)


def test_temperature_drift_monotone() -> None:
    scene = idle_scene({"drift": {"ramp_K_per_s": 0.5, "creep_gain": 0.0}})
    r = Simulator(scene).run(200).resistance_ohm
    assert np.all(np.diff(r, axis=0) > 0)


def test_creep_monotone_towards_gain() -> None:
    p = DriftParams(alpha_per_K=0.0, ramp_K_per_s=0.0, creep_tau_s=0.2, creep_gain=0.1)
    drift = Drift(p, 1, 100.0, stream(0, "drift"))
    q = np.full((300, 1, 9, 3), -0.05)
    out = drift.apply(q, np.arange(300) / 100.0)[:, 0, 0, 0]
    assert np.all(np.diff(out) < 0)
    assert out[0] == -0.05
    assert out[-1] == pytest.approx(-0.05 * 1.1, rel=1e-4)


FAULTS = {"pillars": [
    {"node_id": 1, "taxel": 0, "pillar": "z", "kind": "open", "from_s": 0.05},
    {"node_id": 1, "taxel": 1, "pillar": "x", "kind": "short"},
    {"node_id": 2, "taxel": 2, "pillar": "y", "kind": "stuck", "from_s": 0.1},
    {"node_id": 2, "taxel": 3, "pillar": "z", "kind": "saturated"},
]}


@pytest.mark.parametrize("noise", [False, True])
def test_faults(noise: bool) -> None:
    effects: dict[str, Any] = {"faults": FAULTS}
    if noise:
        effects["noise"] = {}
    scene = idle_scene(effects, loads=[{"kind": "uniform_random"}])
    sim = Simulator(scene)
    r = np.concatenate([sim.run(7).resistance_ohm, sim.run(13).resistance_ohm])
    open_value = FULL if noise else np.inf
    assert np.all(r[:5, 0, 0, 0] < 2000) and np.all(r[5:, 0, 0, 0] == open_value)
    assert np.all(r[:, 0, 1, 1] == 0.0)
    assert np.all(r[10:, 1, 2, 2] == r[10, 1, 2, 2]) and len(set(r[:10, 1, 2, 2])) > 1
    assert np.all(r[:, 1, 3, 0] == FULL)
