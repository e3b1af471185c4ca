"""-v/-q/--log-level on every command: python's logging to stderr, with timestamps."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from skin.cli import main

CONFIGURING = {"basicConfig", "addHandler", "setLevel", "dictConfig", "fileConfig",
               "captureWarnings", "disable"}
STAMP = r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\.\d{3}"


def _sniff(tmp_path: Path, *flags: str, after: tuple[str, ...] = ()) -> list[str]:
    return [*flags, "sniff", "-i", "virtual", "-c", f"log{len(flags)}{len(after)}", "--view",
            "none", "--seconds", "0.05", "--record", str(tmp_path / "r.log"), *after]


def test_v_shows_the_librarys_info_lines_with_a_timestamp(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(_sniff(tmp_path)) == 0
    assert "INFO canbus" not in capsys.readouterr().err  # the library: warnings by default
    for argv in (_sniff(tmp_path, "-v"), _sniff(tmp_path, after=("-v",))):
        assert main(argv) == 0
        err = capsys.readouterr().err
        assert re.search(rf"^{STAMP} INFO canbus\.tools\.recorder: recording to "
                         rf"{re.escape(str(tmp_path / 'r.log'))}$", err, re.M), err
    assert main(_sniff(tmp_path, "--log-level", "debug")) == 0
    assert "INFO canbus.tools.recorder" in capsys.readouterr().err


def test_q_hides_warnings(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cut = tmp_path / "cut.log"
    cut.write_text("(1.000000) can0 080#01\n(1.001000) can0 181#0102")  # killed mid-line
    replay = ["replay", "--partial", "--fast", "-i", "virtual", "-c", "logq", str(cut)]
    assert main(replay) == 0
    captured = capsys.readouterr()
    assert re.search(rf"^{STAMP} WARNING canbus\.tools\.recording: .*cut\.log: frame 2: line 2: "
                     r"cut short before its end of line \(truncated file\); the 1 whole "
                     "frames before it are kept$", captured.err, re.M), captured.err
    assert "sent 1 frames" in captured.out
    for quiet in (["-q", *replay], [*replay, "-q"], ["--log-level", "ERROR", *replay]):
        assert main(quiet) == 0
        assert capsys.readouterr().err == ""


def test_the_library_only_asks_for_its_module_logger() -> None:
    """canbus, decoder, sim and skin's core call getLogger(__name__) and configure nothing."""
    root = Path(__file__).resolve().parents[2]
    for path in sorted(p for pkg in ("canbus", "decoder", "sim", "skin")
                       for p in (root / pkg).rglob("*.py")):
        if path.relative_to(root).as_posix().startswith(("skin/commands/", "skin/cli.py")):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)):
                continue
            name = node.func.attr
            assert name not in CONFIGURING, f"{path}:{node.lineno}: {name}() configures logging"
            if name == "getLogger":
                assert [ast.unparse(a) for a in node.args] == ["__name__"], \
                    f"{path}:{node.lineno}: getLogger({', '.join(map(ast.unparse, node.args))})"


def test_a_bad_level_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["--log-level", "loud", "plan", "--patches", "1", "--rate", "1"])
    assert info.value.code == 2
    assert "invalid choice: 'LOUD'" in capsys.readouterr().err
