"""Every numeric option of every command: a hostile value is refused by argparse, before
any work, in one line; whatever is accepted is a finite number of a sane size."""

from __future__ import annotations

import argparse
import contextlib
import io
import math
from collections.abc import Iterator

import pytest
from hypothesis import given
from hypothesis import strategies as st

from skin.cli import _commands, build_parser
from skin.commands.common import argtypes
from tests.inputs.conftest import examples
from tests.inputs.hostile import HOSTILE_NUMBERS, Result, refused

ALWAYS_WRONG = ("inf", "-inf", "nan", "1e300", "-1e300", "99999999999999999999999", "abc",
                "", "1e", "--x")
"""Values no numeric option may take."""


def _numeric_actions() -> Iterator[tuple[list[str], argparse.Action]]:
    parser = build_parser()
    top = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for command in _commands(top):
        path = command.prog.split()[1:]
        for action in command._actions:
            if action.type is not None and action.type is not argtypes.output_file and \
                    getattr(action.type, "__module__", "") in ("skin.commands.common.argtypes",
                                                                 "skin.commands.train"):
                yield path, action


ACTIONS = [(path, action) for path, action in _numeric_actions()]
IDS = [f"{' '.join(p)} {a.option_strings[-1] if a.option_strings else a.dest}"
       for p, a in ACTIONS]


def test_no_numeric_option_is_left_unranged() -> None:
    parser = build_parser()
    top = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    plain = [f"{command.prog} {action.option_strings}" for command in _commands(top)
             for action in command._actions if action.type in (int, float)]
    assert plain == []
    assert len(ACTIONS) > 60  # every command's options, python-can's bitrates included


COMMANDS = {tuple(c.prog.split()[1:]): c for c in _commands(next(
    a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)))}


def _argv(path: list[str], action: argparse.Action, value: str) -> list[str]:
    if action.option_strings:
        return [*path, f"{action.option_strings[-1]}={value}"]
    # A positional after others: those take a value they accept ("1"), so it is the one tried.
    before = []
    for other in COMMANDS[tuple(path)]._actions:
        if other.dest == action.dest:
            break
        if not other.option_strings and other.nargs is None:
            before.append("1")
    return [*path, "--", *before, value]


PARSER = build_parser()


def parse(argv: list[str]) -> Result:
    """What ``skin ARGV`` says when its arguments are parsed (the parser built once)."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            PARSER.parse_args(argv)
        except SystemExit as exit_:
            return Result(int(exit_.code or 0), "", err.getvalue())
    return Result(0, "", err.getvalue())


@pytest.mark.parametrize(("path", "action"), ACTIONS, ids=IDS)
def test_always_wrong_values_are_refused_in_one_line(path: list[str],
                                                     action: argparse.Action) -> None:
    for value in ALWAYS_WRONG:
        if value == "abc" and action.dest == "hidden":
            continue  # --hidden takes 'auto'; 'abc' is refused below all the same
        result = parse(_argv(path, action, value))
        refused(result)
        assert result.code == 2
        name = action.option_strings[-1] if action.option_strings else action.metavar
        assert str(name) in result.lines[0] or action.dest in result.lines[0]


@pytest.mark.parametrize(("path", "action"), ACTIONS, ids=IDS)
@examples(20)
@given(text=st.one_of(st.sampled_from(HOSTILE_NUMBERS), st.text(max_size=12),
                      st.floats().map(repr), st.integers().map(str)))
def test_any_value_is_a_sane_number_or_refused(path: list[str], action: argparse.Action,
                                              text: str) -> None:
    assert action.type is not None
    try:
        value = action.type(text)
    except (argparse.ArgumentTypeError, ValueError, TypeError):
        if "\x00" not in text and text != "--":  # argparse drops a lone --
            refused(parse(_argv(path, action, text)))
        return
    if value == "auto":
        return
    assert isinstance(value, int | float | dict) and not isinstance(value, bool)
    if isinstance(value, float):
        assert math.isfinite(value)
    if isinstance(value, int | float):
        assert abs(value) <= 2**63
