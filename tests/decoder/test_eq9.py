"""eq9: the paper's Eq. 9 reading against its closed form, and its limits."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from decoder.eq9 import Eq9Decoder
from decoder.reasons import Reason
from skin.constants import DEFAULT_CONSTANTS
from skin.smallstrain import paper_force_from_ratio_change

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels

R0 = DEFAULT_CONSTANTS.nominal_resistance_ohm
ES = DEFAULT_CONSTANTS.axial_stiffness_N
LIMIT = ((1 - DEFAULT_CONSTANTS.max_strain) ** 2, (1 + DEFAULT_CONSTANTS.max_strain) ** 2)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(LIMIT[0], LIMIT[1]), min_size=27, max_size=27))
def test_eq9_is_the_closed_form(ratios: list[float]) -> None:
    """F_i = E·S·(1 - √(R'_i/R_i)) per pillar; pillar z gives Fz, x gives -(...), y +(...)
    as the paper reads them (skin.smallstrain, which `skin model approx` uses)."""
    ratio = np.array(ratios).reshape(1, 9, 3)
    out = Eq9Decoder().decode(ratio * R0)
    assert out.valid.all()
    closed = ES * (1.0 - np.sqrt(ratio))
    np.testing.assert_allclose(out.force_N[..., 2], closed[..., 0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(out.force_N[..., 0], closed[..., 1], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(out.force_N[..., 1], -closed[..., 2], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(out.force_N, paper_force_from_ratio_change(ratio - 1.0),
                               rtol=1e-12, atol=1e-12)
    z_only = Eq9Decoder().decode(ratio[..., :1] * R0[:1])
    np.testing.assert_array_equal(z_only.force_N[..., 2], out.force_N[..., 2])
    assert not z_only.force_N[..., :2].any()


def test_eq9_keeps_its_digits_near_zero_load() -> None:
    """1 - √(1+q) by -q/(1+√(1+q)): a 1 nN press comes back to about six digits."""
    q = -2e-11  # Fz = E·S·q/2 to first order: 1 nN
    out = Eq9Decoder().decode(np.full((1, 9, 1), R0[0] * (1.0 + q)))
    np.testing.assert_allclose(out.force_N[..., 2], -ES * q / 2.0, rtol=1e-5)


def test_eq9_flags_strain_beyond_the_limit_and_faults() -> None:
    r = np.full((1, 9, 3), 1.0) * R0
    r[0, 0, 0] = R0[0] * LIMIT[1] * 1.01  # stretched past 20 %
    r[0, 1, 1] = R0[1] * LIMIT[0] * 0.99  # compressed past 20 %
    r[0, 2, 2] = np.inf
    r[0, 3, 0] = np.nan
    out = Eq9Decoder().decode(r)
    assert out.reason[0, :4].tolist() == [Reason.OUT_OF_RANGE, Reason.OUT_OF_RANGE,
                                          Reason.OPEN, Reason.NON_FINITE]
    assert out.valid[0, 4:].all() and np.all(np.isfinite(out.force_N))
