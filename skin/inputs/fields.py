"""Typed, ranged fields of a parsed document (TOML, msgpack, JSON) and of a command line's
values: the one vocabulary of checks every reader of canskin's inputs uses.

A bool is not a number (``True`` is an ``int`` to Python, never to a user), every number
is finite and inside its range, a table holds only the keys it knows (:func:`known_keys`:
``unknown key; known: ...``), a node-ID is in 1..127 (:func:`node_id`) and a COB-ID has
11 bits (:func:`cob_id`). Every failure is a :class:`~skin.errors.ConfigError` naming the
dotted field and what it got (a value of the wrong kind or range: a :class:`FieldError`,
``must be <want>, got <got>``); a command line's argument types
(``skin.commands.common.argtypes``) call the same checks and say the same to argparse,
with the text as it was typed.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence
from typing import Any

from skin.errors import ConfigError

MAX_TEXT = 4096
NODE_IDS = range(1, 128)
"""CANopen node-IDs (CiA 301): 1..127."""
NODE_ID = "a node-ID in 1..127"
UNCONFIGURED = 0xFF
"""The node-ID of a device that waits for LSS to give it one (CiA 305)."""
COB_IDS = range(0, 0x800)
"""COB-IDs of CAN base frames: 11 bits, 0x000..0x7FF."""
COB_ID = "an 11-bit COB-ID in 0x000..0x7FF"
SERIAL_NUMBERS = range(0, 1 << 32)
"""Serial numbers of object 0x1018 sub 4 (UNSIGNED32)."""
SERIAL_NUMBER = "a serial number in 0..0xFFFFFFFF"


class FieldError(ConfigError):
    """A value its field does not take: ``must be <want>, got <got>``. A command line's
    argument type says the same with the text as the user typed it."""

    def __init__(self, field: str, want: str, got: str) -> None:
        self.want = want
        super().__init__(field, f"must be {want}, got {got}")


def short(value: Any, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters (an integer of any size included)."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10 ** 30:
        return f"{'-' if value < 0 else ''}an integer of {len(hex(value)) * 4 - 8} bits"
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}..."


def shown(value: Any) -> str:
    """A value as a message shows it: its type and a short repr."""
    kind = {bool: "a boolean", int: "an integer", float: "a number", str: "a string",
            list: "an array", dict: "a table", bytes: "bytes"}.get(type(value),
                                                                  type(value).__name__)
    return f"{kind} {short(value)}"


def _num(value: float) -> str:
    return str(value) if isinstance(value, int) else f"{value:g}"


def bounds(low: float | None = None, high: float | None = None, *,
           above: float | None = None, unit: str = "") -> str:
    """A range as a message says it: ``in 1..127``, ``>= 0 s``, ``> 0 s and <= 60 s``
    (``above``: strictly more); "" for no bound."""
    unit = f" {unit}" if unit else ""
    if above is not None:
        top = f" and <= {_num(high)}{unit}" if high is not None else ""
        return f"> {_num(above)}{unit}{top}"
    if low is not None and high is not None:
        return f"in {_num(low)}..{_num(high)}{unit}"
    if low is not None:
        return f">= {_num(low)}{unit}"
    return "" if high is None else f"<= {_num(high)}{unit}"


def _an_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def integer(value: Any, field: str, low: int | None = None, high: int | None = None, *,
            unit: str = "") -> int:
    """An integer (not a bool) in ``low..high``."""
    want = bounds(low, high, unit=unit)
    if not _an_int(value):
        raise FieldError(field, f"an integer{' ' + want if want else ''}", shown(value))
    if (low is not None and value < low) or (high is not None and value > high):
        raise FieldError(field, want, short(value))
    return int(value)


def number(value: Any, field: str, low: float | None = None, high: float | None = None, *,
           above: float | None = None, unit: str = "") -> float:
    """A finite number (an integer is taken) in ``low..high``; ``above``: strictly more."""
    want = bounds(low, high, above=above, unit=unit)
    if not isinstance(value, int | float) or isinstance(value, bool):
        raise FieldError(field, f"a number{' ' + want if want else ''}", shown(value))
    out = float(value) if abs(value) < 2 ** 1023 or isinstance(value, float) else math.inf
    if not math.isfinite(out):
        raise FieldError(field, f"a finite number{' ' + want if want else ''}", short(value))
    if (above is not None and not out > above) or (low is not None and out < low) or \
            (high is not None and out > high):
        raise FieldError(field, want, short(value))
    return out


def boolean(value: Any, field: str) -> bool:
    if not isinstance(value, bool):
        raise FieldError(field, "true or false", shown(value))
    return value


def text(value: Any, field: str, max_len: int = MAX_TEXT) -> str:
    if not isinstance(value, str):
        raise FieldError(field, "a string", shown(value))
    if len(value) > max_len:
        raise ConfigError(field, f"longer than {max_len} characters ({len(value)})")
    return value


def choice(value: Any, choices: Sequence[str], field: str) -> str:
    """One of the strings ``choices``."""
    out = text(value, field)
    if out not in choices:
        raise FieldError(field, f"one of {', '.join(choices)}", short(out))
    return out


def typed(value: Any, kind: type, field: str, low: float | None = None,
          high: float | None = None) -> Any:
    """A value of ``kind`` (bool, int, float or str), numbers in ``low..high``."""
    if kind is bool:
        return boolean(value, field)
    if kind is int:
        return integer(value, field, None if low is None else int(low),
                       None if high is None else int(high))
    if kind is float:
        return number(value, field, low, high)
    if kind is str:
        return text(value, field)
    raise FieldError(field, kind.__name__, shown(value))


def is_node_id(value: Any) -> bool:
    """Whether ``value`` is a CANopen node-ID (an integer in 1..127)."""
    return _an_int(value) and value in NODE_IDS


def node_id(value: Any, field: str, *, unconfigured: bool = False) -> int:
    """A CANopen node-ID, 1..127; ``unconfigured``: :data:`UNCONFIGURED` too."""
    if is_node_id(value) or (unconfigured and _an_int(value) and value == UNCONFIGURED):
        return int(value)
    want = NODE_ID
    if unconfigured:
        want += f" or 0x{UNCONFIGURED:X} (unconfigured)"
    raise FieldError(field, want, short(value) if _an_int(value) else shown(value))


def _hex(value: int) -> str:
    return f"{'-' if value < 0 else ''}0x{abs(value):X}" if abs(value) < 1 << 64 \
        else short(value)


def cob_id(value: Any, field: str) -> int:
    """An 11-bit COB-ID, 0x000..0x7FF."""
    if _an_int(value) and value in COB_IDS:
        return int(value)
    raise FieldError(field, COB_ID, _hex(value) if _an_int(value) else shown(value))


def serial_number(value: Any, field: str) -> int:
    """A serial number of object 0x1018 sub 4: 0..0xFFFFFFFF."""
    if _an_int(value) and value in SERIAL_NUMBERS:
        return int(value)
    raise FieldError(field, SERIAL_NUMBER, short(value) if _an_int(value) else shown(value))


def path(value: Any, field: str) -> str:
    """A file path: a non-empty string without NUL characters."""
    out = text(value, field)
    if not out or "\x00" in out:
        raise FieldError(field, "a file path", short(out))
    return out


def table(value: Any, field: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise FieldError(field, "a table", shown(value))
    return value


def array(value: Any, field: str, max_len: int | None = None) -> list[Any]:
    if not isinstance(value, list):
        raise FieldError(field, "an array", shown(value))
    if max_len is not None and len(value) > max_len:
        raise ConfigError(field, f"lists {len(value)} values, at most {max_len} allowed")
    return value


def known_keys(data: Mapping[str, Any], known: Collection[str], where: str, *,
               what: str = "key") -> None:
    """ConfigError naming the first key of ``data`` not in ``known`` (``where`` "": a key
    of the document itself), and listing the known ones: ``unknown key; known: a, b``."""
    for key in data:
        if key not in known:
            listed = ", ".join(sorted(known)) or "none"
            raise ConfigError(f"{where}.{key}" if where else key,
                              f"unknown {what}; known: {listed}")
