"""`skin bench paper`: the paper's Figures 8-10 as ours, its claims beside, and the JSON keys
the issue names."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from skin.benchmarks.paper import KEYS, PAPER, claims, relative_errors
from skin.cli import main

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels


def test_bench_paper_quick_writes_the_figures_and_the_claims(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]
                                                            ) -> None:
    out, png = tmp_path / "paper.json", tmp_path / "paper.png"
    assert main(["bench", "paper", "--quick", "--json", str(out), "--png", str(png)]) == 0
    result = json.loads(out.read_text())
    for key in ("iterations_to_goal", "max_rel_err_pct", "median_rel_err_pct",
                "share_below_1pct", "edge_vs_centre_rmse"):
        assert key in result and key in result["paper"]
    assert result["seed_pairs"] == [[1, 2]]
    run = result["runs"][0]
    assert len(run["shown_true_N"]) == len(run["shown_decoded_N"]) == 90
    curve = run["mse_curve"]
    # trainlm stops at the goal: the curve ends at or below 1e-4 N² the first time it gets there
    assert result["iterations_to_goal"] == len(curve) and curve[-1] <= 1e-4 < min(curve[:-1])
    assert 0.0 <= result["share_below_1pct"] <= 1.0 and result["max_rel_err_pct"] > 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = capsys.readouterr().out
    assert "121 iterations" in text and "not more than 9 %" in text


def test_bench_paper_refuses_a_bad_png_before_any_work(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "paper", "--png", str(tmp_path / "paper.jpg")]) == 1
    assert "--png" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_the_claims_are_measured_as_the_paper_reads_its_figure_10() -> None:
    true = np.full((10, 9), 2.0)
    decoded = true.copy()
    decoded[:, 0] = 2.2  # an edge taxel 10 % off on every sample
    decoded[:, 4] = 2.01  # the centre taxel 0.5 % off
    c = claims(true, decoded, np.ones((10, 9), dtype=bool))
    assert c["max_rel_err_pct"] == pytest.approx(10.0)
    assert c["share_below_1pct"] == pytest.approx(80 / 90)
    assert c["edge_vs_centre_rmse"] == pytest.approx(np.sqrt(0.04 / 8) / 0.01)
    assert c["edge_vs_centre_rmse"] > PAPER["edge_vs_centre_rmse"]  # the edges worst
    flagged = np.ones((10, 9), dtype=bool)
    flagged[:, 0] = False  # what a decoder refused is not counted
    assert claims(true, decoded, flagged)["max_rel_err_pct"] == pytest.approx(0.5)
    assert relative_errors(np.array([4.0]), np.array([3.0]))[0] == pytest.approx(25.0)
    assert set(KEYS) == set(PAPER)
