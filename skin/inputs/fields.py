"""Typed, ranged fields of a parsed document (TOML, msgpack): one check per kind of value.

A bool is not a number (``True`` is an ``int`` to Python, never to a user), every number
is finite and inside its range, and every failure is a
:class:`~skin.errors.ConfigError` naming the dotted field and what it got.
"""

from __future__ import annotations

import math
from typing import Any

from skin.errors import ConfigError

MAX_TEXT = 4096


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


def _bounds(low: float | None, high: float | None) -> str:
    if low is not None and high is not None:
        return f" in {low:g}..{high:g}"
    if low is not None:
        return f" >= {low:g}"
    return "" if high is None else f" <= {high:g}"


def integer(value: Any, field: str, low: int | None = None, high: int | None = None) -> int:
    """An integer (not a bool) in ``low..high``."""
    if not isinstance(value, int) or isinstance(value, bool):
        raise ConfigError(field, f"must be an integer{_bounds(low, high)}, got {shown(value)}")
    if (low is not None and value < low) or (high is not None and value > high):
        raise ConfigError(field, f"must be{_bounds(low, high)}, got {short(value)}")
    return value


def number(value: Any, field: str, low: float | None = None, high: float | None = None, *,
           above: float | None = None) -> float:
    """A finite number (an integer is taken) in ``low..high``; ``above``: strictly more."""
    want = f"> {above:g}{' and <= ' + format(high, 'g') if high is not None else ''}" \
        if above is not None else _bounds(low, high).strip()
    if not isinstance(value, int | float) or isinstance(value, bool):
        raise ConfigError(field, f"must be a number{' ' + want if want else ''}, got "
                          f"{shown(value)}")
    out = float(value) if abs(value) < 2 ** 1023 or isinstance(value, float) else math.inf
    if not math.isfinite(out):
        raise ConfigError(field, f"must be a finite number, got {short(value)}")
    if (above is not None and not out > above) or (low is not None and out < low) or \
            (high is not None and out > high):
        raise ConfigError(field, f"must be {want}, got {short(value)}")
    return out


def boolean(value: Any, field: str) -> bool:
    if not isinstance(value, bool):
        raise ConfigError(field, f"must be true or false, got {shown(value)}")
    return value


def text(value: Any, field: str, max_len: int = MAX_TEXT) -> str:
    if not isinstance(value, str):
        raise ConfigError(field, f"must be a string, got {shown(value)}")
    if len(value) > max_len:
        raise ConfigError(field, f"longer than {max_len} characters ({len(value)})")
    return value


def path(value: Any, field: str) -> str:
    """A file path: a non-empty string without NUL characters."""
    out = text(value, field)
    if not out or "\x00" in out:
        raise ConfigError(field, f"must be a file path, got {short(out)}")
    return out


def table(value: Any, field: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise ConfigError(field, f"must be a table, got {shown(value)}")
    return value


def array(value: Any, field: str, max_len: int | None = None) -> list[Any]:
    if not isinstance(value, list):
        raise ConfigError(field, f"must be an array, got {shown(value)}")
    if max_len is not None and len(value) > max_len:
        raise ConfigError(field, f"lists {len(value)} values, at most {max_len} allowed")
    return value


def known_keys(data: dict[str, Any], known: Any, where: str) -> None:
    """ConfigError naming the first key of ``data`` not in ``known``."""
    for key in data:
        if key not in known:
            listed = ", ".join(sorted(known)) or "none"
            raise ConfigError(f"{where}.{key}" if where else key,
                              f"unknown key; known: {listed}")
