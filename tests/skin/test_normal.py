"""z-only mode: Fz from pillar z alone, exact under pure normal load."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from skin.normal import normal_force_from_ratio_change, normal_force_from_resistance
from skin.tripod import ratio_change_from_force, resistance_from_force


@given(st.floats(0.0, 9.0))
@settings(max_examples=200, deadline=None)
def test_round_trip_pure_normal(fz: float) -> None:
    qz = ratio_change_from_force(np.array([0.0, 0.0, fz]))[0]
    result = normal_force_from_ratio_change(qz)
    assert bool(result.valid)
    assert abs(float(result.force_N) - fz) <= 1e-9 * max(fz, 1e-3)


def test_batch_over_samples_and_taxels() -> None:
    rng = np.random.default_rng(7)
    fz = rng.uniform(0.0, 5.0, size=(50, 9))
    force = np.zeros((50, 9, 3))
    force[..., 2] = fz
    r_z = resistance_from_force(force)[..., 0]
    result = normal_force_from_resistance(r_z)
    assert result.force_N.shape == (50, 9)
    np.testing.assert_allclose(result.force_N, fz, rtol=1e-9, atol=1e-12)


def test_invalid_inputs_are_masked_and_finite() -> None:
    r = np.array([np.nan, np.inf, -np.inf, 0.0, -3.0, 1e9, 1000.0])
    result = normal_force_from_resistance(r)
    assert result.valid.tolist() == [False] * 6 + [True]
    assert np.all(np.isfinite(result.force_N))
    assert abs(result.force_N[-1]) < 1e-12
