"""The one vocabulary of checked fields (``skin.inputs.fields``): every value in its range
comes back as it was, every other one is refused naming the field, the range and what it
got; a command line's argument types take exactly what a file's field takes; and every
TOML reader refuses an unknown key through the one check, listing the known ones."""

from __future__ import annotations

import argparse
import copy
import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from canbus.master.hostconfig import host_config_from_dict
from canbus.master.zenoh_settings import zenoh_settings_from_table
from sim.probe import load_probe_scene
from sim.scene import scene_from_dict
from skin.commands.common import argtypes
from skin.constants import SensorConstants
from skin.errors import ConfigError
from skin.inputs import fields
from tests.inputs.conftest import examples
from tests.inputs.hostile import to_toml

NOT_INTEGERS = st.one_of(st.booleans(), st.floats(), st.text(max_size=8), st.none(),
                         st.lists(st.integers(), max_size=2))
"""Values of a kind no integer field takes (``True`` is an int to Python, not to a user)."""
FIELD = st.from_regex(r"[a-z_]{1,8}(\[[0-9]\])?(\.[a-z_]{1,8}){0,2}", fullmatch=True)


def _refusal(check: Callable[[], Any]) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        check()
    assert "\n" not in str(info.value)
    return info.value


@examples(200)
@given(value=st.integers(), field=FIELD)
def test_a_node_id_is_1_to_127(value: int, field: str) -> None:
    if 1 <= value <= 127:
        assert fields.node_id(value, field) == value
        assert fields.is_node_id(value)
        return
    err = _refusal(lambda: fields.node_id(value, field))
    assert not fields.is_node_id(value)
    assert err.field == field
    assert err.problem == f"must be a node-ID in 1..127, got {fields.short(value)}"


@examples(100)
@given(value=NOT_INTEGERS, field=FIELD)
def test_a_node_id_of_another_kind_is_named_by_its_kind(value: Any, field: str) -> None:
    err = _refusal(lambda: fields.node_id(value, field))
    assert err.field == field
    assert err.problem == f"must be a node-ID in 1..127, got {fields.shown(value)}"


@pytest.mark.parametrize("value", [0xFF, 0, 128])
def test_an_unconfigured_node_id_is_taken_only_where_asked(value: int) -> None:
    if value == fields.UNCONFIGURED:
        assert fields.node_id(value, "node_id", unconfigured=True) == value
    else:
        err = _refusal(lambda: fields.node_id(value, "node_id", unconfigured=True))
        assert err.problem == (f"must be a node-ID in 1..127 or 0xFF (unconfigured), got "
                               f"{value}")
    assert _refusal(lambda: fields.node_id(value, "node_id")).problem.startswith(
        "must be a node-ID in 1..127, got ")


@examples(200)
@given(value=st.one_of(st.integers(), st.integers(-0x900, 0x900)), field=FIELD)
def test_a_cob_id_has_11_bits(value: int, field: str) -> None:
    if 0 <= value <= 0x7FF:
        assert fields.cob_id(value, field) == value
        return
    err = _refusal(lambda: fields.cob_id(value, field))
    assert err.field == field
    assert err.problem.startswith("must be an 11-bit COB-ID in 0x000..0x7FF, got ")
    got = err.problem.removeprefix("must be an 11-bit COB-ID in 0x000..0x7FF, got ")
    assert got == (f"{'-' if value < 0 else ''}0x{abs(value):X}" if abs(value) < 2**64
                   else fields.short(value))


@examples(100)
@given(value=st.integers(), field=FIELD)
def test_a_serial_number_is_unsigned32(value: int, field: str) -> None:
    if 0 <= value <= 0xFFFF_FFFF:
        assert fields.serial_number(value, field) == value
        return
    err = _refusal(lambda: fields.serial_number(value, field))
    assert (err.field, err.problem) == (
        field, f"must be a serial number in 0..0xFFFFFFFF, got {fields.short(value)}")


@st.composite
def _int_ranges(draw: st.DrawFn) -> tuple[int, int]:
    low = draw(st.integers(-10**20, 10**20))
    return low, low + draw(st.integers(0, 10**6))


@examples(200)
@given(bounds=_int_ranges(), value=st.integers(), field=FIELD)
def test_an_integer_in_its_range_round_trips_and_any_other_is_named(
        bounds: tuple[int, int], value: int, field: str) -> None:
    low, high = bounds
    if low <= value <= high:
        assert fields.integer(value, field, low, high) == value
        return
    err = _refusal(lambda: fields.integer(value, field, low, high))
    assert (err.field, err.problem) == (field, f"must be in {low}..{high}, got "
                                               f"{fields.short(value)}")


@examples(100)
@given(value=NOT_INTEGERS, field=FIELD)
def test_an_integer_of_another_kind_is_named_by_its_kind(value: Any, field: str) -> None:
    err = _refusal(lambda: fields.integer(value, field, 0, 9))
    assert err.problem == f"must be an integer in 0..9, got {fields.shown(value)}"


@examples(200)
@given(low=st.floats(-1e6, 1e6), span=st.floats(0, 1e6),
       value=st.one_of(st.floats(), st.integers()), field=FIELD)
def test_a_number_in_its_range_round_trips_and_any_other_is_named(
        low: float, span: float, value: float, field: str) -> None:
    high = low + span
    if isinstance(value, float) and math.isfinite(value) and low <= value <= high:
        assert fields.number(value, field, low, high) == value
        return
    if isinstance(value, int) and abs(value) < 2**53 and low <= value <= high:
        assert fields.number(value, field, low, high) == float(value)
        return
    err = _refusal(lambda: fields.number(value, field, low, high))
    assert err.field == field
    assert f"in {low:g}..{high:g}" in err.problem
    assert err.problem.endswith(f", got {fields.short(value)}")


@examples(100)
@given(keys=st.lists(st.sampled_from(["a", "b", "c", "d", "e"]), unique=True),
       known=st.sets(st.sampled_from(["a", "b", "c"])), where=st.sampled_from(["", "t.u"]))
def test_an_unknown_key_is_named_with_the_known_ones(keys: list[str], known: set[str],
                                                     where: str) -> None:
    table = dict.fromkeys(keys, 1)
    unknown = [key for key in keys if key not in known]
    if not unknown:
        fields.known_keys(table, known, where)
        return
    err = _refusal(lambda: fields.known_keys(table, known, where))
    assert err.field == (f"{where}.{unknown[0]}" if where else unknown[0])
    assert err.problem == f"unknown key; known: {', '.join(sorted(known)) or 'none'}"


# -- the command line takes what a file takes ----------------------------------------------

CLI_CHECKS: list[tuple[Callable[[str], int], Callable[[Any, str], int]]] = [
    (argtypes.node_id, fields.node_id),
    (argtypes.serial, fields.serial_number),
    (argtypes.patches, lambda v, f: fields.integer(v, f, 1, 127)),
    (argtypes.port, lambda v, f: fields.integer(v, f, 1, 65535)),
]


def _want(check: Callable[[], Any]) -> str | None:
    """What ``check`` says its field must be, or None when it takes the value."""
    try:
        check()
    except fields.FieldError as err:
        return err.want
    return None


@pytest.mark.parametrize(("argument", "check"), CLI_CHECKS,
                         ids=[a.__name__ for a, _ in CLI_CHECKS])
@examples(100)
@given(value=st.one_of(st.integers(-300, 300), st.integers(-10**30, 10**30)),
       spelt=st.sampled_from([str, hex]))
def test_a_command_line_value_is_taken_as_its_field_takes_it(
        argument: Callable[[str], int], check: Callable[[Any, str], int], value: int,
        spelt: Callable[[int], str]) -> None:
    text = spelt(value)
    want = _want(lambda: check(value, "field"))
    if want is None:
        assert argument(text) == value
        return
    with pytest.raises(argparse.ArgumentTypeError) as info:
        argument(text)
    assert str(info.value) == f"must be {want}, got {text!r}"


@examples(100)
@given(value=st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                       st.integers(-10**6, 10**6)))
def test_a_command_line_number_is_taken_as_its_field_takes_it(value: float) -> None:
    text = repr(value)
    want = _want(lambda: fields.number(float(value), "seconds", above=0.0,
                                       high=argtypes.YEAR_S, unit="s"))
    if want is None:
        assert argtypes.seconds(text) == float(value)
        return
    assert "> 0 s and <= 31536000 s" in want
    with pytest.raises(argparse.ArgumentTypeError) as info:
        argtypes.seconds(text)
    assert str(info.value) == f"must be {want}, got {text!r}"


def test_a_command_line_value_that_is_no_number_names_the_range() -> None:
    for argument, want in ((argtypes.node_id, "a node-ID in 1..127"),
                           (argtypes.patches, "a whole number in 1..127")):
        with pytest.raises(argparse.ArgumentTypeError, match=re.escape(
                f"must be {want}, got 'five'")):
            argument("five")


# -- every TOML reader refuses an unknown key through the one check ----------------------

SCENE: dict[str, Any] = {
    "scene": {"name": "t", "mode": "xyz"},
    "patches": [{"node_id": 1}],
    "loads": [{"kind": "indenter"}],
    "effects": {"noise": {}, "faults": {"pillars": [{"node_id": 1, "taxel": 0}]}},
}
HOST: dict[str, Any] = {
    "host": {}, "drift": {}, "contact": {}, "robot": {}, "zenoh": {"tls": {}},
    "patches": [{"node_id": 1, "constants": {}, "contact": {}, "link": "arm", "pose": {}}],
}
PROBE: dict[str, Any] = {"probe": {}, "presses": [{"link": "arm", "point_m": [0.0, 0.0, 0.0]}]}


def _read_probe(doc: dict[str, Any], tmp_path: Path) -> Any:
    path = tmp_path / "probe.toml"
    path.write_text(to_toml(doc))
    return load_probe_scene(path)


READERS: dict[str, tuple[Callable[[dict[str, Any], Path], Any], dict[str, Any],
                         list[tuple[str | int, ...]]]] = {
    "scene": (lambda d, _: scene_from_dict(d), SCENE,
              [(), ("scene",), ("patches", 0), ("loads", 0), ("effects", "noise"),
               ("effects", "faults"), ("effects", "faults", "pillars", 0)]),
    "probe scene": (_read_probe, PROBE, [(), ("probe",), ("presses", 0)]),
    "host config": (lambda d, _: host_config_from_dict(d), HOST,
                    [(), ("host",), ("drift",), ("contact",), ("robot",), ("zenoh",),
                     ("zenoh", "tls"), ("patches", 0), ("patches", 0, "constants"),
                     ("patches", 0, "contact"), ("patches", 0, "pose")]),
    "host config [bus]": (lambda d, _: host_config_from_dict(d),
                          {"bus": {}, "patches": [{"node_id": 1}]}, [("bus",)]),
    "host config [[buses]]": (lambda d, _: host_config_from_dict(d),
                              {"buses": [{"name": "a"}], "patches": [{"node_id": 1}]},
                              [("buses", 0)]),
    "reader's [zenoh]": (lambda d, _: zenoh_settings_from_table(d), {"tls": {}},
                         [(), ("tls",)]),
    "sensor constants": (lambda d, _: SensorConstants.from_dict(d, "constants"), {}, [()]),
}
CASES = [(name, where) for name, (_, _, places) in READERS.items() for where in places]


def _dotted(path: tuple[str | int, ...], prefix: str) -> str:
    out = prefix
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else f"{'.' if out else ''}{part}"
    return out


@pytest.fixture
def refusals(monkeypatch: pytest.MonkeyPatch) -> list[ConfigError]:
    """What :func:`skin.inputs.fields.known_keys` refused while the test ran."""
    seen: list[ConfigError] = []
    shared = fields.known_keys

    def spy(*args: Any, **kwargs: Any) -> None:
        try:
            shared(*args, **kwargs)
        except ConfigError as err:
            seen.append(err)
            raise

    monkeypatch.setattr(fields, "known_keys", spy)
    return seen


@pytest.mark.parametrize(("reader", "where"), CASES,
                         ids=[f"{name}: {_dotted(where, '') or 'top'}" for name, where in CASES])
def test_every_toml_reader_refuses_an_unknown_key_through_the_one_check(
        reader: str, where: tuple[str | int, ...], refusals: list[ConfigError],
        tmp_path: Path) -> None:
    read, base, _ = READERS[reader]
    read(copy.deepcopy(base), tmp_path)  # the document without the key is taken
    assert refusals == []
    doc = copy.deepcopy(base)
    table: Any = doc
    for part in where:
        table = table[part]
    table["colour"] = 1
    with pytest.raises(ConfigError) as info:
        read(doc, tmp_path)
    assert refusals, "refused, but not by skin.inputs.fields.known_keys"
    err = refusals[-1]
    prefix = "constants" if reader == "sensor constants" else \
        "zenoh" if reader == "reader's [zenoh]" else ""
    assert err.field == _dotted((*where, "colour"), prefix)
    assert info.value.field == err.field and info.value.problem == err.problem
    match = re.fullmatch(r"unknown (key|sensor constant); known: (.*)", err.problem)
    assert match is not None, err.problem
    known = match.group(2).split(", ")
    assert known == sorted(known) and "colour" not in known
    assert set(table) - {"colour", "kind"} <= set(known)  # a load's kind picks its table
