"""The analytic decoder: exactness against skin.tripod / skin.normal, and the hard cases."""

from __future__ import annotations

import numpy as np
import pytest

from decoder.analytic import AnalyticDecoder
from decoder.reasons import Reason, reason_name
from decoder.tripod3 import tripod_force_from_ratio_change
from skin.constants import DEFAULT_CONSTANTS
from skin.normal import normal_force_from_resistance
from skin.tripod import force_from_ratio_change, ratio_change_from_force

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels

R0 = DEFAULT_CONSTANTS.nominal_resistance_ohm


def test_fast_tripod_matches_skin_tripod_to_1e_12() -> None:
    rng = np.random.default_rng(0)
    force = rng.uniform(-1, 1, (5000, 3)) * [1.5, 1.5, 2.5] + [0, 0, 2.5]
    q = ratio_change_from_force(force)
    q = np.concatenate((q, rng.uniform(-0.5, 0.6, (5000, 3))))
    fast, valid = tripod_force_from_ratio_change(q, DEFAULT_CONSTANTS)
    ref = force_from_ratio_change(q)
    np.testing.assert_array_equal(valid, ref.valid)
    assert np.max(np.abs(fast - ref.force_N)) < 1e-12
    assert np.max(np.abs(fast[:5000] - force)) < 1e-12


def test_z_only_matches_exact_normal_inverse(synth) -> None:  # type: ignore[no-untyped-def]
    r, _ = synth(200, strength=0.0, noise=False)
    out = AnalyticDecoder().decode(r)
    ref = normal_force_from_resistance(r[..., 0])
    assert out.valid.all()
    assert np.max(np.abs(out.force_N[..., 2] - ref.force_N)) < 1e-9
    assert not out.force_N[..., :2].any()


def _hard_row(pillars: int) -> np.ndarray:
    r = np.tile(R0[:pillars] * 0.97, (1, 9, 1))
    sat = DEFAULT_CONSTANTS.adc_full_scale_code * DEFAULT_CONSTANTS.resistance_lsb_ohm
    r[0, 0, 0] = np.nan
    r[0, 1, 0] = np.inf
    r[0, 2, 0] = -5.0
    r[0, 3, 0] = 0.0
    r[0, 5, 0] = sat
    r[0, 6, 0] = R0[0] * 0.3  # 70 % shorter: past the strain limit
    return r


@pytest.mark.parametrize("pillars", [1, 3])
def test_hard_cases_are_masked_with_reasons_and_the_rest_decode(pillars: int) -> None:
    out = AnalyticDecoder().decode(_hard_row(pillars))
    expected = [Reason.NON_FINITE, Reason.OPEN, Reason.NON_POSITIVE, Reason.SHORT, Reason.OK,
                Reason.SATURATED, Reason.OUT_OF_RANGE, Reason.OK, Reason.OK]
    assert out.reason[0].tolist() == [int(e) for e in expected]
    assert out.valid[0].tolist() == [e == Reason.OK for e in expected]
    assert np.all(np.isfinite(out.force_N))
    assert not out.force_N[0, ~out.valid[0]].any()
    assert np.all(out.force_N[0, out.valid[0], 2] > 0.5)
    assert out.reason_names()[0, 1] == "OPEN" and reason_name(200) == "UNKNOWN(200)"


def test_patches_axis_is_folded_and_restored() -> None:
    r = np.tile(R0 * 0.98, (4, 2, 9, 1))
    out = AnalyticDecoder().decode(r)
    assert out.force_N.shape == (4, 2, 9, 3) and out.valid.shape == (4, 2, 9)


def test_per_taxel_r0_is_used() -> None:
    r0 = np.tile(R0[:1], (9, 1)) * np.linspace(0.95, 1.05, 9)[:, None]
    out = AnalyticDecoder(r0_ohm=r0).decode(r0[None])
    np.testing.assert_allclose(out.force_N, 0.0, atol=1e-9)
