"""Loads: shapes and physical sanity."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from sim import Simulator, scene_from_dict
from sim.loads import (
    GraspParams,
    Indenter,
    IndenterParams,
    Slide,
    SlideParams,
    UniformRandom,
    UniformRandomParams,
    make_load,
)
from sim.rng import stream

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels

PITCH = 0.015


def test_uniform_random_is_the_papers_protocol() -> None:
    f = UniformRandom(UniformRandomParams(), 2, stream(0, "x")).forces(0, 5000)
    assert f.shape == (5000, 2, 9, 3)
    assert np.all(f[..., :2] == 0.0)
    assert f[..., 2].min() >= 0.0 and f[..., 2].max() <= 5.0
    assert f[..., 2].mean() == pytest.approx(2.5, abs=0.03)
    corr = np.corrcoef(f[:, 0, :, 2].T)
    assert np.abs(corr - np.eye(9)).max() < 0.06  # independent taxels


def test_uniform_random_shear_bounds() -> None:
    f = UniformRandom(UniformRandomParams(shear_max_N=0.5), 1, stream(0, "x")).forces(0, 2000)
    assert np.abs(f[..., :2]).max() <= 0.5 and f[..., :2].std() > 0.2


def test_indenter_is_a_sphere() -> None:
    p = IndenterParams()
    f = Indenter(p, 1, stream(0, "x"), PITCH).forces(0, 2000)[:, 0]
    assert np.all(f[..., :2] == 0.0)
    assert np.all(f[..., 2] >= 0.0) and f[..., 2].max() <= p.fz_max_N
    touched = f[..., 2].sum(axis=1) > 0
    assert 0.5 < touched.mean() < 1.0  # random points and depths: some presses miss every taxel
    # a sphere: the force falls off with distance from the most loaded taxel
    peak = np.argmax(f[..., 2], axis=1)
    corner_peak = np.isin(peak, [0, 2, 6, 8]) & touched
    opposite = 8 - peak[corner_peak]
    assert np.all(f[corner_peak, opposite, 2] <= f[corner_peak, 4, 2])


def test_slide_moves_with_friction_along_motion() -> None:
    p = SlideParams(angle_deg=30.0, friction=0.3)
    slide = Slide(p, 2, 100.0, PITCH)
    f = slide.forces(0, 400)
    np.testing.assert_array_equal(f[:, 0], f[:, 1])
    fz = f[:, 0, :, 2]
    np.testing.assert_allclose(np.hypot(f[:, 0, :, 0], f[:, 0, :, 1]), 0.3 * fz)
    angle = np.arctan2(f[:, 0, :, 1], f[:, 0, :, 0])[fz > 0]
    np.testing.assert_allclose(angle, np.radians(30.0))
    pressed = fz.sum(axis=1) > 0.5
    centroid_x = (fz * (np.arange(9) % 3 - 1)).sum(axis=1)[pressed] / fz.sum(axis=1)[pressed]
    assert np.mean(np.diff(centroid_x) >= 0) > 0.95  # moving in +x, but for the wrap-arounds
    assert centroid_x.min() < -0.9 and centroid_x.max() > 0.9
    np.testing.assert_array_equal(slide.forces(123, 5), f[123:128])


def test_grasp_cycles() -> None:
    p = GraspParams(period_s=1.0)
    load = make_load("grasp", p, 2, rate_hz=100.0, pitch_m=PITCH, seed=3, name="loads[0]")
    f = load.forces(0, 300)
    total = f[..., 2].sum(axis=(1, 2))
    assert total[0] == 0.0 and total[100] == 0.0
    assert total[50] == total[0:100].max()
    assert np.abs(f[..., :2]).max() <= p.shear_max_N
    np.testing.assert_array_equal(load.forces(140, 30), f[140:170])


def test_idle_and_unlisted_patches_carry_no_force() -> None:
    data: dict[str, Any] = {
        "scene": {"name": "t"},
        "patches": [{"node_id": 1}, {"node_id": 2}, {"node_id": 3}],
        "loads": [{"kind": "uniform_random", "patches": [2]}, {"kind": "idle", "patches": [1]}],
    }
    f = Simulator(scene_from_dict(data)).run(10).force_N
    assert np.all(f[:, [0, 2]] == 0.0) and np.all(f[:, 1, :, 2] > 0.0)
