"""Figures are never cut: plain aligned text when piped, a split rich table on a narrow
terminal."""

from __future__ import annotations

import io

from rich.console import Console

from skin.commands.common.tables import plain, show

COLUMNS = ["decoder", "AveRelErr %", "floored %", "x oracle", "RMSE %FS", "max rel floored %",
           "train s", "patch-samples/s", "latency us"]
ROWS = [["analytic", "60.556", "26.591", "-", "9.300", "234.71", "0.000", "3,283,123", "33.2"],
        ["lm-mlp", "1.692", "0.481", "-", "0.224", "12.48", "0.122", "2,021,000", "72.0"]]


def test_piped_output_is_a_plain_table_with_every_figure_whole() -> None:
    out = io.StringIO()
    show("decoders", COLUMNS, ROWS, file=out)
    text = out.getvalue()
    assert "\x1b" not in text and "…" not in text
    lines = text.splitlines()
    assert lines[0] == "decoders" and lines[1].split()[0] == "decoder"
    assert lines[3].split() == ROWS[0] and lines[4].split() == ROWS[1]
    assert text == plain("decoders", COLUMNS, ROWS)


def test_an_80_column_terminal_gets_every_figure_in_parts() -> None:
    console = Console(width=80, force_terminal=True, color_system=None, file=io.StringIO())
    show("decoders", COLUMNS, ROWS, console=console)
    text = console.file.getvalue()  # type: ignore[attr-defined]
    assert "…" not in text
    assert max(len(line) for line in text.splitlines()) <= 80
    for row in ROWS:
        for cell in row:
            assert cell in text
    assert text.count("analytic") == 2  # the label column repeated in each part
