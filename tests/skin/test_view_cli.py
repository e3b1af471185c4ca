"""`skin view`'s arguments, layouts and glyphs: what is refused, and how patches are placed."""

from __future__ import annotations

import builtins
import math
from pathlib import Path
from typing import Any

import pytest

from skin.cli import main
from skin.commands.view.layout import Layout, layout_from_positions, parse_layout
from skin.commands.view.term import INFERNO, arrow, colour, reason_code

FILES = Path(__file__).resolve().parents[1] / "files"


@pytest.fixture
def recording(tmp_path: Path) -> Path:
    path = tmp_path / "run.log"
    path.write_text("(1000.000000) can0 080#01\n(1000.000100) can0 1C1#0000000000000000\n",
                    encoding="utf-8")
    return path


@pytest.mark.parametrize(("args", "message"), [
    (["--png", "x.png"], "--png: draws a recording: give FILE"),
    (["--at", "1"], "--at: applies to a recording FILE"),
    (["--fast"], "--fast: applies to a recording FILE"),
    (["REC", "--png", "x.png", "--gif", "x.gif"], "--gif: one output at a time, got --png, --gif"),
    (["REC", "--snapshot", "--plot", "x.png"], "--snapshot: one output at a time"),
    (["REC", "--at", "1"], "--at: goes with --png or --snapshot"),
    (["REC", "--from", "1"], "--from: goes with --gif, --mp4 or --plot"),
    (["REC", "--gif", "x.gif", "--from", "2", "--to", "1"], "--to: must be after --from (2 s)"),
    (["REC", "--png", "x.png", "--at", "-1"], "USAGE argument --at: must be in 0..10000000000 s"),
    (["REC", "--png", "x.png", "--at", "nan"], "USAGE argument --at: must be a finite number"),
    (["REC", "--plot", "x.png", "--patch", "1"], "--plot: needs --patch N and --taxel K"),
    (["REC", "--plot", "x.png", "--patch", "1", "--taxel", "9"],
     "USAGE argument --taxel: must be in 0..8"),
    (["REC", "--patch", "1"], "--patch: goes with --plot"),
    (["REC", "--raw"], "--raw: goes with --plot"),
    (["--decode"], "--decode: needs --config host.toml"),
    (["--scene", "indenter", "--config", "h.toml"], "--scene: give the layout by --scene or"),
    (["--scale", "0"], "USAGE argument --scale: must be > 0 N"),
    (["--scale", "inf"], "USAGE argument --scale: must be a finite number > 0 N"),
    (["--refresh", "-1"], "USAGE argument --refresh: must be > 0 Hz"),
    (["REC", "--png", "x.jpg"], "--png: the file must end in .png, got 'x.jpg'"),
    (["REC", "--png", "x.png", "--at", "5"], "--at: 5 s is past the recording's end (0.000 s)"),
    (["REC", "--layout", "1=0"], "--layout: expected NODE=X,Y (node-ID 1..127, metres within "
     "±1000), got"),
    (["REC", "--layout", "1=0,0", "1=1,1"], "--layout: patch 1 is placed twice"),
    (["REC", "--plot", "x.png", "--patch", "9", "--taxel", "0"],
     "--patch: patch 9 has no force sample in"),
])
def test_bad_arguments_fail_in_one_line(args: list[str], message: str, recording: Path,
                                        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    argv = ["view", *(str(recording) if a == "REC" else a for a in args),
            "-i", "virtual", "-c", "never-opened"]
    if message.startswith("USAGE "):  # a value out of its range: argparse's one line
        with pytest.raises(SystemExit) as usage:
            main(argv)
        assert usage.value.code == 2
        err = capsys.readouterr().err
        assert err.startswith(f"skin view: error: {message.removeprefix('USAGE ')}"), err
    else:
        assert main(argv) == 1
        err = capsys.readouterr().err
        assert err.startswith(f"skin: error: {message}"), err
    assert err.count("\n") == 1
    assert list(tmp_path.glob("x.*")) == []  # nothing half-written


def test_a_recording_may_follow_the_layout(recording: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["view", "--snapshot", "--layout", "1=0,0", "2=0.05,0", str(recording)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("skin view run.log  t 0.000 s  2 patches")
    assert "patch 1        waiting  patch 2        waiting" in out


def test_a_damaged_or_unknown_recording_is_named(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    cut = tmp_path / "cut.log"
    cut.write_text("(1000.000000) can0 080#01\n(1000.0001", encoding="utf-8")
    assert main(["view", str(cut), "--snapshot"]) == 1
    assert capsys.readouterr().err.startswith(f"skin: error: {cut}: frame 2: line 2: cut short")
    assert main(["view", str(tmp_path / "run.txt"), "--snapshot"]) == 1
    assert "unknown recording format '.txt'" in capsys.readouterr().err


def test_pictures_without_matplotlib_or_ffmpeg_say_what_is_missing(
        recording: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("PATH", "")  # no ffmpeg
    assert main(["view", str(recording), "--mp4", "x.mp4"]) == 1
    assert capsys.readouterr().err == ("skin: error: --mp4: needs ffmpeg on PATH (e.g. apt-get "
                                       "install ffmpeg); --gif needs only Pillow\n")
    real = builtins.__import__

    def no_matplotlib(name: str, *args: Any, **kwargs: Any) -> Any:
        if name == "matplotlib" or name.startswith("matplotlib."):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_matplotlib)
    for flag in ("--png", "--gif"):
        assert main(["view", str(recording), flag, f"x.{flag[2:]}"]) == 1
        assert capsys.readouterr().err == (f"skin: error: {flag}: needs matplotlib: pip "
                                           "install 'canskin[plot]'\n")


def test_a_bus_that_cannot_be_opened_is_named(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["view", "-i", "socketcan", "-c", "no-such-can9", "--seconds", "0.1"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("skin: error: cannot open the bus socketcan:no-such-can9: ")
    assert err.count("\n") == 1


def test_patches_are_placed_by_position_highest_y_on_top() -> None:
    layout = parse_layout(["1=0,0", "2=0.05,0", "3=0.1,0.001", "4=0,0.05", "5=0.1,0.05"])
    assert layout.grid() == {1: (0, 1), 2: (1, 1), 3: (2, 1), 4: (0, 0), 5: (2, 0)}
    same = Layout({1: (0.0, 0.0), 2: (0.0, 0.0)})
    assert same.grid() == {1: (0, 0), 2: (1, 0)}  # one place: side by side
    grown = layout.including([9, 7])
    assert grown.positions[7] == pytest.approx((0.15, 0.0)) and \
        grown.positions[9] == pytest.approx((0.2, 0.0))
    assert Layout.row([3, 1, 2]).grid() == {1: (0, 0), 2: (1, 0), 3: (2, 0)}
    mixed = layout_from_positions({1: (0.0, 0.0), 2: None, 3: (0.05, 0.1)}, "config")
    assert mixed.positions[2] == pytest.approx((0.1, 0.0))  # unplaced: after, bottom row


def test_glyphs_colours_and_reason_codes() -> None:
    assert [arrow(1, 0), arrow(0.5, 0.5), arrow(0, 1), arrow(-1, 0), arrow(0, -1)] == \
        ["⇒", "↗", "⇑", "⇐", "⇓"]
    assert arrow(0.05, 0.05) == " " and arrow(math.nan, 0.0) == " "
    assert arrow(0.2, -0.2) == "↘" and arrow(-0.3, -0.1) == "←"
    assert colour(0.0, 5.0) == INFERNO[0] and colour(5.0, 5.0) == INFERNO[-1]
    assert colour(-1.0, 5.0) == INFERNO[0] and colour(9.0, 5.0) == INFERNO[-1]
    assert colour(2.5, 5.0) == INFERNO[5]
    assert [reason_code(c)[0] for c in (1, 2, 3, 4, 5, 6, 7, 8, 0xFF, 42)] == \
        ["NaN", "NEG", "OPN", "SHT", "SAT", "RNG", "MIS", "FLT", "---", "R42"]
