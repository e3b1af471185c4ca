"""The exact tripod model: round trips, stable numerics, limits."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.errors import ConfigError, StrainLimitError
from skin.tripod import (
    displacement_from_force,
    force_from_ratio_change,
    force_from_resistance,
    ratio_change_from_displacement,
    ratio_change_from_force,
    resistance_from_force,
    strain_from_ratio_change,
)

C = DEFAULT_CONSTANTS

NAMED_FORCES = {
    "zero": (0.0, 0.0, 0.0),
    "press 5 N": (0.0, 0.0, 5.0),
    "press 1 uN": (0.0, 0.0, 1e-6),
    "pure shear x": (2.0, 0.0, 0.0),
    "pure shear -y": (0.0, -2.0, 0.0),
    "mixed": (1.0, -0.5, 3.0),
    "pull": (0.0, 0.0, -4.0),
}


def _rel_err(got: np.ndarray, want: np.ndarray) -> float:
    scale = max(float(np.max(np.abs(want))), 1e-300)
    return float(np.max(np.abs(got - want)) / scale)


@pytest.mark.parametrize("name", NAMED_FORCES)
def test_round_trip_named_cases(name: str) -> None:
    force = np.array(NAMED_FORCES[name])
    result = force_from_ratio_change(ratio_change_from_force(force))
    assert bool(result.valid)
    if name == "zero":
        assert np.all(result.force_N == 0.0)
    else:
        assert _rel_err(result.force_N, force) < 1e-9


@pytest.mark.parametrize("name", NAMED_FORCES)
def test_round_trip_through_ohms(name: str) -> None:
    # In ohms, R = R0·(1 + q) rounds q to ~1e-16·R0/|R - R0|: a micro-newton
    # press keeps ~1e-14 N absolute accuracy, not 1e-9 relative.
    force = np.array(NAMED_FORCES[name])
    result = force_from_resistance(resistance_from_force(force))
    assert bool(result.valid)
    np.testing.assert_allclose(result.force_N, force, rtol=1e-9, atol=1e-12)


forces_3d = st.tuples(
    st.floats(-2.0, 2.0), st.floats(-2.0, 2.0), st.floats(0.0, 5.0)
).map(np.array)


@given(forces_3d)
@settings(max_examples=300, deadline=None)
def test_round_trip_random_forces(force: np.ndarray) -> None:
    q = ratio_change_from_force(force)
    result = force_from_ratio_change(q)
    assert bool(result.valid)
    # Relative to the force's size; absolute near zero load.
    scale = max(float(np.linalg.norm(force)), 1e-3)
    assert float(np.max(np.abs(result.force_N - force))) / scale < 1e-9


@given(arrays(np.float64, (4, 9, 3), elements=st.floats(0.0, 5.0)))
@settings(max_examples=30, deadline=None)
def test_vectorised_matches_one_by_one(batch: np.ndarray) -> None:
    batch[..., :2] -= 2.5
    batch[..., :2] *= 0.4
    together = ratio_change_from_force(batch)
    alone = np.array([ratio_change_from_force(f) for f in batch.reshape(-1, 3)])
    np.testing.assert_allclose(together.reshape(-1, 3), alone, rtol=1e-13, atol=1e-16)


def test_near_zero_load_has_no_cancellation() -> None:
    # A 1 nN press changes R by ~1e-11 relative; the force must still come back
    # to many digits, which a naive 1 - sqrt(R'/R) could not give.
    force = np.array([0.0, 0.0, 1e-9])
    q = ratio_change_from_force(force)
    assert q[0] < 0
    back = force_from_ratio_change(q).force_N
    assert abs(back[2] - 1e-9) / 1e-9 < 1e-6
    assert abs(strain_from_ratio_change(1e-17) - 5e-18) < 1e-30


def test_pure_press_is_carried_by_pillar_z_at_small_strain() -> None:
    # The truss is statically determinate: at small load a vertical press
    # leaves the diagonal pillars unstrained to first order.
    q = ratio_change_from_force(np.array([0.0, 0.0, 1e-3]))
    e = strain_from_ratio_change(q)
    assert e[0] == pytest.approx(-1e-3 / C.axial_stiffness_N, rel=1e-4)
    assert abs(e[1]) < 1e-3 * abs(e[0]) and abs(e[2]) < 1e-3 * abs(e[0])


def test_full_scale_press_is_a_realistic_strain() -> None:
    e = strain_from_ratio_change(ratio_change_from_force(np.array([0.0, 0.0, 5.0])))
    assert 0.03 < -e[0] < 0.10


def test_equilibrium_holds_at_the_solution() -> None:
    force = np.array([0.7, -0.3, 4.0])
    u = displacement_from_force(force)
    q = ratio_change_from_displacement(u)
    np.testing.assert_allclose(force_from_ratio_change(q).force_N, force, rtol=1e-12)


@pytest.mark.parametrize("force", [(0.0, 0.0, 30.0), (0.0, 0.0, 10.5), (20.0, 0.0, 0.0)])
def test_force_past_the_limit_is_refused(force: tuple[float, float, float]) -> None:
    with pytest.raises(StrainLimitError, match="flat index 0"):
        ratio_change_from_force(np.array(force))


def test_error_names_the_offending_sample() -> None:
    batch = np.zeros((5, 3))
    batch[3] = (0.0, 0.0, 40.0)
    with pytest.raises(StrainLimitError, match="flat index 3"):
        ratio_change_from_force(batch)


def test_bad_force_shape_and_values() -> None:
    with pytest.raises(ValueError, match="last axis of 3"):
        ratio_change_from_force(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="NaN or infinity"):
        ratio_change_from_force(np.array([0.0, np.nan, 1.0]))


def test_inverse_masks_impossible_and_non_finite_inputs() -> None:
    r0 = C.nominal_resistance_ohm
    resistances = np.array(
        [
            r0,
            [np.nan, r0[1], r0[2]],
            [np.inf, r0[1], r0[2]],
            [0.0, r0[1], r0[2]],
            [-5.0, r0[1], r0[2]],
            [r0[0] * 0.1, r0[1] * 3.0, r0[2]],  # lengths that cannot meet
        ]
    )
    result = force_from_resistance(resistances)
    assert result.valid.tolist() == [True, False, False, False, False, False]
    assert np.all(np.isfinite(result.force_N))
    assert np.all(result.force_N[1:] == 0.0)


def test_per_pillar_nominal_resistance_is_honoured() -> None:
    r0 = np.array([990.0, 1420.0, 1400.0])
    force = np.array([0.5, 0.2, 2.0])
    r = resistance_from_force(force, r0_ohm=r0)
    np.testing.assert_allclose(force_from_resistance(r, r0_ohm=r0).force_N, force, rtol=1e-10)


def test_constants_are_validated() -> None:
    with pytest.raises(ConfigError, match="youngs_modulus_pa"):
        SensorConstants(youngs_modulus_pa=-1.0)
    with pytest.raises(ConfigError, match=r"sensor\.colour"):
        SensorConstants.from_dict({"colour": 1.0})
    assert SensorConstants.from_dict(C.to_dict()) == C
