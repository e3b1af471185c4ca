"""`skin bench cross --quick --json`: the shipped scenes' matrix and the promise pair by pair,
on a reduced set of scenes and pairs (the full run is `skin bench cross`)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from skin.benchmarks.pairs import PAIRS
from skin.cli import main


def test_bench_cross_reports_the_promise_per_pair(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    import skin.benchmarks.cross
    import skin.benchmarks.runs

    monkeypatch.setattr(skin.benchmarks.runs, "Z_SCENES", ("paper-noisy", "indenter"))
    monkeypatch.setattr(skin.benchmarks.runs, "XYZ_SCENES", ())
    monkeypatch.setattr(skin.benchmarks.cross, "PAIRS", PAIRS[:1])
    monkeypatch.setattr("decoder.registry.available_decoders",
                        lambda: ("analytic", "deconv", "lm-mlp", "hybrid"))
    out = tmp_path / "cross.json"
    assert main(["bench", "cross", "--quick", "--random", "1", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    promise = result["promise"]
    assert {r["decoder"] for r in promise} == {"deconv", "lm-mlp", "hybrid"}
    assert {(r["train"], r["test"]) for r in promise} == {("paper-noisy", "indenter"),
                                                          ("indenter", "paper-noisy")}
    rows = result["pairs"]["rows"]
    assert len(rows) == 2 * 3 and result["pairs"]["random_pairs"] == 1
    for r in [*promise, *rows]:
        assert 0.0 <= r["flagged_home"] <= 1.0 and 0.0 <= r["flagged_away"] <= 1.0
        assert r["home_met"] == (r["flagged_home"] <= 0.05)
    s = result["summary"]
    assert s["rows"] == len(promise) + len(rows)
    text = capsys.readouterr().out
    assert "the promise on the shipped scenes" in text and "flagged at home <= 5 %" in text


def test_bench_cross_refuses_a_bad_random_count(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["bench", "cross", "--random", "-1"])
    assert "--random" in capsys.readouterr().err
