"""The paper's small-strain approximation against the exact model."""

from __future__ import annotations

import numpy as np
import pytest

from skin.smallstrain import (
    approximation_table,
    force_at_strain,
    linear_truss_force,
    paper_force_from_ratio_change,
)
from skin.tripod import ratio_change_from_force, strain_from_ratio_change

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels


def test_table_has_every_load_at_5_10_20_percent() -> None:
    rows = approximation_table()
    by_key = {(r.load, r.strain_pct): r for r in rows}
    for load in ("press", "pull", "shear +x"):
        for strain in (5.0, 10.0, 20.0):
            assert (load, strain) in by_key
    press5 = by_key[("press", 5.0)]
    press10 = by_key[("press", 10.0)]
    assert press5.paper_err_pct is not None and press10.paper_err_pct is not None
    # The error grows with strain: the approximation is a small-strain one.
    assert 5.0 < press5.paper_err_pct < press10.paper_err_pct
    # A pure press collapses the tripod (snap-through) before 20 % strain.
    assert by_key[("press", 20.0)].force_N is None
    pull20 = by_key[("pull", 20.0)]
    assert pull20.force_N is not None and pull20.paper_err_pct is not None
    assert pull20.paper_err_pct > by_key[("pull", 10.0)].paper_err_pct  # type: ignore[operator]


def test_force_at_strain_hits_the_strain() -> None:
    magnitude = force_at_strain((0.0, 0.0, -1.0), 0.10)
    assert magnitude is not None
    e = strain_from_ratio_change(ratio_change_from_force(np.array([0.0, 0.0, -magnitude])))
    assert float(np.max(np.abs(e))) == pytest.approx(0.10, abs=1e-9)


def test_paper_reading_is_right_for_a_tiny_press_but_not_for_shear() -> None:
    press = np.array([0.0, 0.0, 1e-3])
    q = ratio_change_from_force(press)
    np.testing.assert_allclose(paper_force_from_ratio_change(q), press, atol=1e-6)
    shear = np.array([1e-3, 0.0, 0.0])
    q = ratio_change_from_force(shear)
    error = np.linalg.norm(paper_force_from_ratio_change(q) - shear) / 1e-3
    assert error > 0.5  # pillar x leans at 45 degrees: Δl_x is not Δx


@pytest.mark.parametrize("direction", [(0, 0, 1), (1, 0, 0), (0, -1, 0), (1, 1, 2)])
def test_linear_truss_is_exact_in_the_small_strain_limit(direction: tuple[int, ...]) -> None:
    errors = []
    for scale in (1e-3, 1e-4):
        force = scale * np.asarray(direction, dtype=float)
        q = ratio_change_from_force(force)
        errors.append(np.linalg.norm(linear_truss_force(q) - force) / np.linalg.norm(force))
    assert errors[1] < 1e-5
    # First-order accurate: ten times less force, about ten times less error.
    assert errors[1] == pytest.approx(errors[0] / 10, rel=0.05)
