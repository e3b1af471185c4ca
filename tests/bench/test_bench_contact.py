"""`skin bench contact`: every key it promises, from a short run (figures not judged here:
speed is the benchmark's business, not a test's)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import skin.benchmarks.contact
from sim.contact_truth import TrueContact
from skin.benchmarks.contact import Estimate, slip_figures
from skin.cli import main
from skin.contact import summarize
from skin.contact_state import track

SCENE_KEYS = {"cop_err_mm", "net_fz_err_pct_fs", "net_fz_err_pct_fs_stats",
              "slip_delay_cycles", "slip_false_alarms", "slip_missed", "slip_onsets",
              "cop_samples", "cop_missing", "partial_samples", "contact_agreement", "oracle"}


def test_skin_bench_contact_writes_every_key(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(skin.benchmarks.contact, "QUICK", {"steps": 250, "train_steps": 300,
                                                 "cost_cycles": 4, "cost_repeats": 1})
    out = tmp_path / "contact.json"
    assert main(["bench", "contact", "--quick", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert set(result["scenes"]) == {"indenter", "slide", "grasp", "stick-slip"}
    for name, scene in result["scenes"].items():
        assert set(scene) >= SCENE_KEYS, name
        assert set(scene["cop_err_mm"]) == {"p50", "p95"}
        assert {"p50", "max"} <= set(scene["slip_delay_cycles"])
        assert scene["cycles"] == 250 and scene["decoder"] == "deconv"
    stick = result["scenes"]["stick-slip"]
    assert stick["slip_onsets"] == 3  # 2.5 s, a slip onset 0.3 s into each second
    assert stick["params"]["friction"] == 0.5 and result["scenes"]["slide"]["params"][
        "friction"] == 0.3  # the scene's own coefficient
    assert result["scenes"]["indenter"]["slip_onsets"] == 0
    assert result["scenes"]["indenter"]["cop_samples"] > 100
    assert result["cost_ratio"] == pytest.approx(
        result["cost"]["with_us_per_sample"] / result["cost"]["without_us_per_sample"])
    assert result["cost"]["frames_out_with"] == result["cost"]["frames_out_without"] * 8 // 7
    assert result["cost"]["frame_ratio"] == pytest.approx(
        result["cost"]["frame_only_us_per_sample"] / result["cost"]["without_us_per_sample"])
    text = capsys.readouterr().out
    assert "stick-slip" in text and "cost_ratio" in text


def _truth(slip: list[int]) -> TrueContact:
    n = len(slip)
    force = np.zeros((n, 9, 3))
    force[:, 4, 2] = 1.0
    params = skin.benchmarks.contact.ContactParams()
    _, batch = track(summarize(force, np.ones((n, 9), dtype=bool)), params)
    return TrueContact(1, batch, np.array(slip, dtype=bool))


def _estimate(slipping: list[int]) -> Estimate:
    n = len(slipping)
    zeros = np.zeros(n, dtype=bool)
    return Estimate(np.zeros((n, 3)), np.zeros((n, 2)), zeros, ~zeros,
                    np.array(slipping, dtype=bool), zeros)


def test_slip_onsets_are_scored_with_two_cycles_of_tolerance() -> None:
    truth = _truth([0, 0, 0, 0, 0, 1, 1, 1, 0, 0, 0, 0, 1, 1, 0, 0, 0, 0, 0, 0])
    # one cycle early at the first onset, two late at the second, one alarm while sticking
    est = _estimate([0, 0, 0, 0, 1, 1, 1, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 1, 1, 0])
    got = slip_figures(est.slipping, truth)
    assert got == {"slip_onsets": 2, "delays": [-1, 1], "slip_missed": 0,
                   "slip_false_alarms": 1}
    late = _estimate([0] * 8 + [1] + [0] * 11)  # after the truth stopped slipping: missed
    got = slip_figures(late.slipping, truth)
    assert got["slip_missed"] == 2 and got["slip_false_alarms"] == 1 and got["delays"] == []


def test_bad_contact_options_are_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "contact", "--scene", "paper"]) == 1
    assert capsys.readouterr().err.strip() == (
        "skin: error: --scene: one of indenter, slide, grasp, stick-slip, got 'paper'")
    with pytest.raises(SystemExit) as refused:  # argparse's refusal: exit 2, one line
        main(["bench", "contact", "--taxel-contact-N", "-1"])
    assert refused.value.code == 2
    assert capsys.readouterr().err.strip().startswith(
        "skin bench: error: argument --taxel-contact-N: must be in 0..100 N, got '-1'")
