"""The contact summary (skin.contact): rigid-body invariants and no NaN for any input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from skin.contact import ContactParams, PatchGeometry, summarize, taxel_xy
from skin.errors import ConfigError

PITCH = 0.015
forces_N = st.floats(-20.0, 20.0, allow_nan=False)
pressing_N = st.floats(0.2, 20.0)
loads = hnp.arrays(np.float64, (9, 3), elements=forces_N)
masks = hnp.arrays(np.bool_, (9,))
angles = st.floats(-720.0, 720.0, allow_nan=False)
positions = st.tuples(st.floats(-2.0, 2.0), st.floats(-2.0, 2.0))


def one(force: np.ndarray, valid: np.ndarray | None = None, **kwargs: object):  # type: ignore[no-untyped-def]
    v = np.ones(9, dtype=bool) if valid is None else valid
    return summarize(force[None], v[None], **kwargs)  # type: ignore[arg-type]


@given(taxel=st.integers(0, 8), fz=pressing_N, shear=st.tuples(forces_N, forces_N),
       position=positions, angle=angles)
def test_the_cop_of_one_loaded_taxel_is_its_centre(taxel: int, fz: float,
                                                   shear: tuple[float, float],
                                                   position: tuple[float, float],
                                                   angle: float) -> None:
    force = np.zeros((9, 3))
    force[taxel] = (*shear, fz)
    geometry = PatchGeometry(PITCH, position, angle)
    s = one(force, geometry=geometry)
    assert s.cop_defined[0] and s.taxels_in_contact[0] == 1
    np.testing.assert_allclose(s.cop_m[0], taxel_xy(PITCH)[taxel], atol=1e-15)
    np.testing.assert_allclose(s.cop_placed_m[0], geometry.place(taxel_xy(PITCH)[taxel]),
                               atol=1e-12)
    np.testing.assert_allclose(s.force_N[0], force[taxel], atol=0)


@given(force=loads, valid=masks, angle=angles, position=positions)
def test_turning_the_placement_turns_the_cop_and_the_shear(force: np.ndarray, valid: np.ndarray,
                                                          angle: float,
                                                          position: tuple[float, float]) -> None:
    straight = one(force, valid, geometry=PatchGeometry(PITCH, position, 0.0))
    turned = one(force, valid, geometry=PatchGeometry(PITCH, position, angle))
    r = PatchGeometry(orientation_deg=angle).rotation
    np.testing.assert_array_equal(turned.cop_m, straight.cop_m)  # the patch frame stays
    np.testing.assert_allclose(turned.cop_placed_m[0] - position,
                               r @ (straight.cop_placed_m[0] - position), atol=1e-12)
    np.testing.assert_allclose(turned.force_placed_N[0, :2], r @ straight.force_N[0, :2],
                               atol=1e-9)
    assert turned.force_placed_N[0, 2] == straight.force_N[0, 2]
    assert math.isclose(np.hypot(*turned.force_placed_N[0, :2]),
                        np.hypot(*straight.force_N[0, :2]), rel_tol=1e-12, abs_tol=1e-12)


SUBNORMAL_ON_0 = np.zeros((9, 3))
SUBNORMAL_ON_0[0, 2] = 5e-324  # the smallest subnormal: taxel 0 alone in contact


@given(force=loads, valid=masks, threshold=st.floats(0.0, 5.0))
@example(force=SUBNORMAL_ON_0, valid=np.ones(9, dtype=bool), threshold=0.0)
def test_the_net_force_and_torque_are_the_sums_over_the_taxels_in_contact(
        force: np.ndarray, valid: np.ndarray, threshold: float) -> None:
    s = one(force, valid, params=ContactParams(taxel_contact_N=threshold))
    contact = valid & (force[:, 2] > threshold)
    np.testing.assert_array_equal(s.contact_taxels[0], contact)
    assert s.taxels_in_contact[0] == contact.sum() and s.valid_taxels[0] == valid.sum()
    np.testing.assert_allclose(s.force_N[0], force[contact].sum(axis=0), atol=1e-9)
    r = np.zeros((9, 3))
    r[:, :2] = taxel_xy(PITCH)
    torque = np.cross(r[contact], force[contact]).sum(axis=0)
    np.testing.assert_allclose(s.torque_Nm[0], torque, atol=1e-10)
    if contact.any():  # the CoP is the Fz-weighted mean, inside the taxels' hull
        # weights scaled by the largest: the same mean, and no product underflows to 0 when
        # every Fz in contact is subnormal (5e-324 N on one taxel: the CoP is its centre)
        weight = force[contact, 2] / force[contact, 2].max()
        np.testing.assert_allclose(s.cop_m[0], (taxel_xy(PITCH)[contact] * weight[:, None])
                                   .sum(0) / weight.sum(), atol=1e-12)
        assert np.all(np.abs(s.cop_m[0]) <= PITCH * (1 + 1e-12))
    else:
        assert not s.cop_defined[0] and not s.cop_m.any() and s.tangential_ratio[0] == 0


QUARTER = np.array([2, 5, 8, 1, 4, 7, 0, 3, 6])
"""Taxel k of a pattern turned by 90° counter-clockwise on the grid goes to taxel QUARTER[k]."""


@given(force=loads, valid=masks)
def test_a_load_pattern_turned_a_quarter_turns_cop_shear_and_torque(force: np.ndarray,
                                                                     valid: np.ndarray) -> None:
    turned = np.empty_like(force)
    turned_valid = np.empty_like(valid)
    turned[QUARTER] = np.stack([-force[:, 1], force[:, 0], force[:, 2]], axis=1)
    turned_valid[QUARTER] = valid
    a, b = one(force, valid), one(turned, turned_valid)
    quarter = np.array([[0.0, -1.0], [1.0, 0.0]])
    np.testing.assert_allclose(b.cop_m[0], quarter @ a.cop_m[0], atol=1e-12)
    np.testing.assert_allclose(b.force_N[0, :2], quarter @ a.force_N[0, :2], atol=1e-9)
    np.testing.assert_allclose(b.torque_Nm[0, :2], quarter @ a.torque_Nm[0, :2], atol=1e-10)
    assert b.force_N[0, 2] == pytest.approx(a.force_N[0, 2], abs=1e-9)
    assert b.torque_Nm[0, 2] == pytest.approx(a.torque_Nm[0, 2], abs=1e-10)
    assert b.tangential_ratio[0] == pytest.approx(a.tangential_ratio[0], rel=1e-9, abs=1e-12)


anything = st.floats(allow_nan=True, allow_infinity=True)


@settings(max_examples=300)
@given(force=hnp.arrays(np.float64, (3, 9, 3), elements=anything), valid=hnp.arrays(
    np.bool_, (3, 9)), threshold=st.floats(0.0, 1e300), friction=st.floats(1e-300, 1e300))
def test_no_nan_for_any_input(force: np.ndarray, valid: np.ndarray, threshold: float,
                              friction: float) -> None:
    params = ContactParams(taxel_contact_N=threshold, friction=friction)
    s = summarize(force, valid, params=params)
    for name in ("force_N", "torque_Nm", "cop_m", "cop_placed_m", "force_placed_N"):
        assert np.isfinite(getattr(s, name)).all(), name
    assert not np.isnan(s.tangential_ratio).any() and (s.tangential_ratio >= 0).all()
    assert (s.valid_taxels <= valid.sum(axis=1)).all()
    assert not (s.taxel_slip & ~s.contact_taxels).any()
    assert not (s.slip & ~s.cop_defined).any() and not (s.near_slip & ~s.cop_defined).any()


def test_zero_load_and_all_invalid_say_so_without_nan() -> None:
    zero = one(np.zeros((9, 3)))
    assert not zero.cop_defined[0] and zero.taxels_in_contact[0] == 0
    assert zero.valid_taxels[0] == 9 and not zero.force_N.any() and not zero.near_slip[0]
    nothing = one(np.full((9, 3), 7.0), np.zeros(9, dtype=bool))
    assert nothing.valid_taxels[0] == 0 and not nothing.force_N.any()
    assert not nothing.cop_defined[0] and not nothing.cop_m.any()
    vanishing = np.zeros((9, 3))
    vanishing[4] = (1.0, 0.0, 5e-324)  # the smallest normal force there is
    s = one(vanishing, params=ContactParams(taxel_contact_N=0.0))
    assert s.cop_defined[0] and not s.cop_m.any() and s.tangential_ratio[0] == math.inf


def test_the_friction_cone_per_patch_and_per_taxel() -> None:
    force = np.zeros((9, 3))
    force[4] = (0.5, 0.0, 1.0)  # ratio 0.5: on the cone of mu = 0.5
    force[0] = (0.0, 0.41, 1.0)  # 0.41: inside, but within 20 % of it (0.4)
    force[8] = (0.0, 0.0, 1.0)
    s = one(force, params=ContactParams(friction=0.5, near_slip_margin=0.2))
    assert s.taxel_slip[0].tolist() == [False, False, False, False, True, False, False,
                                       False, False]
    assert s.taxel_near_slip[0][[0, 4]].all() and not s.taxel_near_slip[0][8]
    assert s.tangential_ratio[0] == pytest.approx(np.hypot(0.5, 0.41) / 3)
    assert not s.slip[0] and not s.near_slip[0]


@pytest.mark.parametrize(("field", "value"), [
    ("taxel_contact_N", -0.1), ("onset_N", math.nan), ("release_N", 0.5), ("release_N", 0.0),
    ("friction", 0.0), ("near_slip_margin", 1.0), ("near_slip_margin", -0.1),
    ("friction", True)])
def test_bad_params_name_their_field(field: str, value: float) -> None:
    with pytest.raises(ConfigError, match=f"^{field}: "):
        ContactParams(**{field: value})


@pytest.mark.parametrize(("kwargs", "field"), [
    ({"pitch_m": 0.0}, "pitch_m"), ({"position_m": (0.0, math.inf)}, "position_m"),
    ({"orientation_deg": math.nan}, "orientation_deg")])
def test_bad_geometry_names_its_field(kwargs: dict[str, object], field: str) -> None:
    with pytest.raises(ConfigError, match=f"^{field}: "):
        PatchGeometry(**kwargs)  # type: ignore[arg-type]


def test_shapes_are_checked() -> None:
    with pytest.raises(ValueError, match="force_N"):
        summarize(np.zeros((9, 3)), np.ones(9, dtype=bool))
    with pytest.raises(ValueError, match="valid"):
        summarize(np.zeros((2, 9, 3)), np.ones((3, 9), dtype=bool))


def test_a_torque_beyond_float64_makes_the_row_say_nothing_never_inf() -> None:
    """Hypothesis found it: forces whose sums fit float64 but whose torque Σ x·Fy − Σ y·Fx
    does not (taxel 2 at x = +1 pushing +y, taxel 6 at y = +1 pushing -x)."""
    force = np.zeros((9, 3))
    force[2] = (0.0, 8.99e307, 1.0)
    force[6] = (-8.99e307, 0.0, 1.0)
    s = one(force, params=ContactParams(taxel_contact_N=0.0))
    assert np.isfinite(s.torque_Nm).all() and np.isfinite(s.force_N).all()
