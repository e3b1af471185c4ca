"""Tables of figures that are always read whole: a rich table on a terminal, as narrow as
its numbers (headers wrap at spaces, a table wider than the terminal is split into parts
that repeat its first column), and plain aligned text when the output is not a terminal
(a file, a pipe, a log). A number is never cut."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import IO, Any

GAP = 2  # spaces between plain columns; rich pads 1 each side


def show(title: str, columns: Sequence[str], rows: Sequence[Sequence[str]], *,
         file: IO[str] | None = None, console: Any = None, caption: str = "",
         labels: int = 1) -> None:
    """Print ``rows`` under ``columns``; the first ``labels`` columns are labels (left-
    justified, repeated in every part of a split table), the others figures."""
    stream = file or sys.stdout
    if console is None and not stream.isatty():
        stream.write(plain(title, columns, rows, caption, labels))
        return
    from rich.console import Console

    console = console or Console(file=stream)
    for part in _parts(columns, rows, console.width, labels):
        console.print(_rich(title, [columns[i] for i in part],
                            [[row[i] for i in part] for row in rows], caption, labels))


def plain(title: str, columns: Sequence[str], rows: Sequence[Sequence[str]],
          caption: str = "", labels: int = 1) -> str:
    """The table as aligned text, every column as wide as its widest cell or header."""
    widths = [max([len(columns[i]), *(len(row[i]) for row in rows)])
              for i in range(len(columns))]

    def line(cells: Sequence[str]) -> str:
        out = [c.ljust(w) if i < labels else c.rjust(w)
               for i, (c, w) in enumerate(zip(cells, widths, strict=True))]
        return (" " * GAP).join(out).rstrip()

    text = [title, line(columns), "-" * len(line(columns)), *(line(r) for r in rows)]
    if caption:
        text.append(caption)
    return "\n".join(text) + "\n"


def _width(column: str, rows: Sequence[Sequence[str]], i: int) -> int:
    """The narrowest a column can be: its widest cell, or its longest header word."""
    return max([*(len(w) for w in column.split()), *(len(row[i]) for row in rows), 1])


def _parts(columns: Sequence[str], rows: Sequence[Sequence[str]], width: int,
           labels: int) -> list[list[int]]:
    """Column indexes of each part, each part as wide as the terminal at most."""
    needs = [_width(c, rows, i) + 3 for i, c in enumerate(columns)]  # padding and rule
    heads = list(range(min(labels, len(columns))))
    parts: list[list[int]] = []
    current, used = list(heads), sum(needs[i] for i in heads)
    for i in range(len(heads), len(columns)):
        if used + needs[i] > width and len(current) > len(heads):
            parts.append(current)
            current, used = list(heads), sum(needs[h] for h in heads)
        current.append(i)
        used += needs[i]
    parts.append(current)
    return parts


def _rich(title: str, columns: Sequence[str], rows: Sequence[Sequence[str]],
          caption: str, labels: int) -> Any:
    from rich import box
    from rich.table import Table

    table = Table(title=title, title_justify="left", caption=caption or None,
                  caption_justify="left", box=box.SIMPLE_HEAD, pad_edge=False)
    for i, column in enumerate(columns):
        table.add_column(column, justify="left" if i < labels else "right",
                         min_width=_width(column, rows, i), overflow="fold")
    for row in rows:
        table.add_row(*row)
    return table
