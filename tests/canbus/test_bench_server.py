"""``skin bench server``: runs end to end and writes the figures it names (not timed: the
figures themselves are measured by running it, never asserted here)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from skin.benchmarks.server import check_answers
from skin.cli import main


def test_check_answers_takes_only_whole_answers_in_order() -> None:
    expected = [0x181, 0x201, 0x182, 0x202]
    frames = [(0.000, 0x080), (0.001, 0x181), (0.002, 0x201), (0.003, 0x182), (0.004, 0x202),
              (0.010, 0x080), (0.011, 0x181), (0.012, 0x182), (0.013, 0x201), (0.014, 0x202),
              (0.020, 0x080), (0.021, 0x181), (0.022, 0x201), (0.023, 0x182),
              (0.030, 0x080), (0.031, 0x181), (0.032, 0x181), (0.033, 0x201), (0.034, 0x182),
              (0.035, 0x202), (0.036, 0x701)]
    result = check_answers(frames, expected)
    assert result["checked"] == 4 and result["complete"] == 1  # swapped, short, repeated
    assert result["latency_ms"] == pytest.approx([4.0, 4.0, 3.0, 5.0])


def test_bench_server_writes_its_figures(tmp_path: Path, udp_channel: str, udp_port: int,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "server.json"
    assert main(["bench", "server", "--patches", "2", "--seconds", "0.3", "--rounds", "1",
                 "--channel", udp_channel, "--port", str(udp_port), "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    for key in ("cpu_us_per_frame", "send_us_per_frame", "patches_per_core_at_100hz"):
        assert result[key] > 0
    assert set(result["answer_ms"]) >= {"p50", "p99"}
    assert result["answer_ms"]["p50"] > 0 and result["answers_checked"] >= 20
    assert result["frames_sent"] == 14 * result["per_round"][0]["syncs"]
    assert "python-can send of the same frames" in capsys.readouterr().out


def test_bench_server_refuses_bad_sizes(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as refused:
        main(["bench", "server", "--patches", "0"])
    assert refused.value.code == 2
    assert "argument --patches: must be in 1..127" in capsys.readouterr().err
