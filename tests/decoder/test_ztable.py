"""The tabulated z-only inverse against the exact Newton solver of skin.normal."""

from __future__ import annotations

import numpy as np
import pytest

from decoder.ztable import normal_table
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.normal import normal_force_from_ratio_change

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels


def test_interpolant_error_below_1e_9_newton_over_the_valid_range() -> None:
    table = normal_table(DEFAULT_CONSTANTS)
    rng = np.random.default_rng(0)
    q = np.concatenate((rng.uniform(table.q_lo, table.q_hi, 20_000),
                        np.linspace(table.q_lo, table.q_hi, 5_001)))
    force, valid = table.evaluate(q)
    exact = normal_force_from_ratio_change(q)
    assert valid.all() and exact.valid.all()
    assert np.max(np.abs(force - exact.force_N)) < 1e-9


def test_range_covers_past_full_scale_and_rejects_outside() -> None:
    table = normal_table(DEFAULT_CONSTANTS)
    force, valid = table.evaluate(np.array([table.q_lo - 1e-6, table.q_hi + 1e-6, np.nan,
                                            np.inf, -np.inf, 0.0]))
    assert valid.tolist() == [False, False, False, False, False, True]
    assert np.all(np.isfinite(force))
    assert table.evaluate(np.array([table.q_lo]))[0][0] > 1.9 * DEFAULT_CONSTANTS.full_scale_force_N


def test_other_constants_get_their_own_table() -> None:
    soft = SensorConstants(youngs_modulus_pa=8e6)
    q = np.array([-0.05, -0.02, 0.01])
    force, _ = normal_table(soft).evaluate(q)
    np.testing.assert_allclose(force, normal_force_from_ratio_change(q, soft).force_N,
                               atol=1e-9)
