"""Helpers of the hostile-input suite: run ``skin`` in-process, judge its answer, mutate.

:func:`run` calls ``skin.cli.main`` with stdout and stderr captured and a hang guard (a
timer that interrupts a command still running after :data:`HANG_S`: a hang is a failure,
not a slow machine). :func:`refused` is the promise every broken input is held to: a
non-zero exit, one line on stderr naming the problem, no traceback, and not the
catch-all's "unexpected" line (which would mean no reader checked it).
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import io
import json
import math
import signal
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hypothesis import strategies as st

HANG_S = 120.0
"""A command still running after this long is hung (the slowest here takes well under 5 s)."""


class HungError(Exception):
    pass


@dataclass(frozen=True)
class Result:
    code: int
    out: str
    err: str

    @property
    def lines(self) -> list[str]:
        return [line for line in self.err.splitlines() if line.strip()]


@contextlib.contextmanager
def _hang_guard() -> Iterator[None]:
    def interrupt(signum: int, frame: Any) -> None:
        raise HungError(f"still running after {HANG_S:g} s")

    before = signal.signal(signal.SIGALRM, interrupt)
    signal.setitimer(signal.ITIMER_REAL, HANG_S)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, before)


def run(*argv: str | Path) -> Result:
    """``skin ARGV`` in this process."""
    from skin.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), _hang_guard():
        try:
            code = main([str(a) for a in argv])
        except SystemExit as exit_:
            code = exit_.code if isinstance(exit_.code, int) else 1
    return Result(int(code), out.getvalue(), err.getvalue())


def refused(result: Result) -> None:
    """Non-zero exit, one line on stderr, no traceback, not the catch-all."""
    assert result.code != 0, f"accepted: {result.out[-300:]!r}"
    assert len(result.lines) == 1, result.err[-2000:]
    line = result.lines[0]
    assert "error" in line and "Traceback" not in result.err, result.err[-2000:]
    assert "unexpected" not in line, line


def answered(result: Result) -> None:
    """Either the command did its work (exit 0) or it refused in one line."""
    if result.code != 0:
        refused(result)


def message_of(call: Any, kind: type[Exception]) -> str | None:
    """The message of the ``kind`` error ``call()`` raises, None if it raises none."""
    try:
        call()
    except kind as err:
        return str(err)
    return None


def fingerprint(folder: Path) -> dict[str, str]:
    """Every file under ``folder``: name -> hash of its bytes (to see that none changed)."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


HOSTILE_NUMBERS = ("inf", "-inf", "nan", "NaN", "-1", "0", "1e300", "-1e300", "1e-320",
                   "99999999999999999999999", "0x7FFFFFFF", "1.5", "abc", "", " ", "1e",
                   "--", "0b101", "+inf", "1_0", "٣")
"""Command-line values that are wrong for (nearly) every numeric option."""


def hostile_values() -> st.SearchStrategy[Any]:
    """Values a parsed document may hold where another was wanted."""
    return st.one_of(
        st.sampled_from([True, False, -1, 0, 10**30, -(10**30), 2**63, 1e300, -1e300,
                         math.nan, math.inf, -math.inf, "", "x", "\x00", "1", [], [1, 2],
                         {}, {"a": 1}, [[[[]]]], 0.5, 128, 65536]),
        st.integers(), st.floats(), st.text(max_size=5),
    )


def mutate_bytes(data: bytes, draw: Any) -> bytes:
    """One damage a file can have: cut, bytes flipped, bytes put in, or a non-UTF-8 byte."""
    kind = draw(st.sampled_from(("cut", "flip", "insert", "non-utf8", "zero")))
    if not data:
        return b"\xff"
    at = draw(st.integers(0, len(data) - 1))
    if kind == "cut":
        return data[:at]
    if kind == "flip":
        count = draw(st.integers(1, 8))
        out = bytearray(data)
        for k in range(count):
            out[(at + k * 7) % len(out)] ^= draw(st.integers(1, 255))
        return bytes(out)
    if kind == "insert":
        return data[:at] + draw(st.binary(min_size=1, max_size=16)) + data[at:]
    if kind == "zero":
        return data[:at] + bytes(draw(st.integers(1, 64))) + data[at + 64:]
    return data[:at] + b"\xff\xfe" + data[at:]


@dataclass(frozen=True)
class Deep:
    """``value`` inside ``depth`` arrays (written as text: no recursion)."""

    value: Any
    depth: int


def inline_toml(value: Any) -> str:
    """``value`` as an inline TOML value (tables inline, floats as TOML spells nan/inf)."""
    if isinstance(value, Deep):
        return "[" * value.depth + inline_toml(value.value) + "]" * value.depth
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(inline_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{json.dumps(str(k))} = {inline_toml(v)}"
                               for k, v in value.items()) + "}"
    raise TypeError(type(value))


def to_toml(doc: dict[str, Any]) -> str:
    """A document as TOML: one ``key = inline value`` line per top-level key."""
    return "".join(f"{json.dumps(key)} = {inline_toml(value)}\n" for key, value in doc.items())


def _paths(value: Any, path: tuple[Any, ...] = ()) -> Iterator[tuple[Any, ...]]:
    yield path
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _paths(item, (*path, key))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            yield from _paths(item, (*path, index))


def mutate_document(doc: Any, draw: Any) -> Any:
    """One damage to a parsed document: a value replaced by a hostile one, a key deleted or
    added, or a value nested deeply."""
    doc = copy.deepcopy(doc)
    paths = [p for p in _paths(doc) if p]
    path = draw(st.sampled_from(paths))
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    kind = draw(st.sampled_from(("replace", "replace", "replace", "delete", "add", "deep")))
    if kind == "replace":
        parent[path[-1]] = draw(hostile_values())
    elif kind == "delete":
        del parent[path[-1]]
    elif kind == "add" and isinstance(parent, dict):
        parent[draw(st.sampled_from(("extra", "x_m", "", "node_id ")))] = draw(hostile_values())
    else:
        parent[path[-1]] = Deep(parent[path[-1]], draw(st.sampled_from((20, 200, 3000))))
    return doc
