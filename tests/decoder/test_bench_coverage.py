"""`skin bench`: every error beside the share of the taxels it covers; a figure over no
taxel is named in the first line and makes the run exit 3, never a 0 % that looks perfect."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import skin.benchmarks.decoders as benchmark
from skin.commands.bench.report import print_decoders, uncovered
from tests.decoder.conftest import crosstalk_matrix, make_data

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels


def _part(masked: slice) -> dict[str, Any]:
    r, f = make_data(40, seed=1)
    r_test, f_test = make_data(10, seed=2)
    r_test[masked] = np.inf  # open pillars: masked taxels
    return benchmark.bench_decoders([(r, f, r_test, f_test)], crosstalk_matrix(0.05), "z",
                                    ["analytic"], batch=64, repeats=1, speed=False)


def test_each_row_carries_the_share_it_covers() -> None:
    part = _part(slice(0, 4))
    (row,) = part["decoders"]
    assert row["covered_pct"] == pytest.approx(60.0)  # 4 of 10 samples' taxels masked
    assert row["masked"] == 36


def test_a_figure_over_nothing_is_named_first(capsys: pytest.CaptureFixture[str]) -> None:
    part = _part(slice(None))
    (row,) = part["decoders"]
    assert row["covered_pct"] == 0.0 and np.isnan(row["ave_rel_err_floored_pct"])
    result = {"scenes": [{"scene": "paper", "noise": False, **part}], "seeds": 1,
              "table1": [], "goal_units": "N",
              "hidden_auto": {"candidates": [5, 14], "start": 20, "curve": [], "hidden": 9,
                              "stopped": "-", "ave_rel_err_pct": 1.0,
                              "ave_rel_err_floored_pct": 1.0},
              "analytic_taxel_samples_per_s": {"z": 1.0, "xyz": 1.0}, "xyz_speed": [],
              "lm_vs_scipy": {"samples": 1, "params": 1, "ours_s_per_iteration": 1.0,
                              "ours_nit": 1, "ours_mse": 1.0, "ours_s": 1.0,
                              "scipy_s_per_iteration": 1.0, "scipy_njev": 1, "scipy_mse": 1.0,
                              "speedup_per_iteration": 1.0}}
    assert uncovered(result) == ["analytic on paper"]
    print_decoders(result)
    out = capsys.readouterr().out
    assert out.splitlines()[0] == ("no result: every taxel masked for analytic on paper: "
                                   "those figures cover nothing")
    row = next(line for line in out.splitlines() if line.lstrip("│ ").startswith("analytic"))
    assert " 0.00 " in row  # covers 0.00 %, its errors "-"
