"""TOML documents (scenes, host configs), read with every failure as one line.

:func:`read_toml` reads a file of at most :data:`MAX_BYTES`, decodes it as strict UTF-8,
parses it with :mod:`tomllib` and walks the result once (without recursion): nested at
most :data:`MAX_DEPTH` tables and arrays deep, and no float that is NaN or infinite
anywhere (none of canskin's files has a use for one, and JSON cannot carry them). Every
failure is a :class:`~skin.errors.ConfigError` naming the file and, where there is one,
the dotted field (``loads[0].position_m[1]``).
"""

from __future__ import annotations

import math
import os
import re
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from skin.errors import ConfigError

MAX_BYTES = 4 << 20
MAX_DEPTH = 16
_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def dotted(path: tuple[str | int, ...]) -> str:
    """``("loads", 0, "patches")`` -> ``loads[0].patches``; odd keys quoted."""
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            key = part if _BARE_KEY.fullmatch(part) else f'"{part}"'
            out += f".{key}" if out else key
    return out


def read_toml(path: str | os.PathLike[str], what: str = "file") -> dict[str, Any]:
    """The checked document of the TOML file ``path`` (``what`` names it in messages that
    have no field: ``config``, ``scene``)."""
    source = os.fspath(path)
    try:
        with Path(path).open("rb") as handle:
            raw = handle.read(MAX_BYTES + 1)
    except FileNotFoundError as err:
        raise ConfigError(what, f"no such file {source!r}") from err
    except IsADirectoryError as err:
        raise ConfigError(what, f"{source!r} is a folder, not a file") from err
    except OSError as err:
        raise ConfigError(what, f"cannot read {source!r}: {err.strerror}") from err
    if len(raw) > MAX_BYTES:
        raise ConfigError(what, f"larger than the limit of {MAX_BYTES >> 20} MiB for a TOML "
                          "file", source=source)
    return parse_toml(raw, source, what)


def parse_toml(raw: bytes, source: str, what: str = "file") -> dict[str, Any]:
    """:func:`read_toml` of bytes already read from ``source``."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        line = raw.count(b"\n", 0, err.start) + 1
        raise ConfigError(what, f"not UTF-8 text: byte 0x{raw[err.start]:02X} at line {line} "
                          f"(offset {err.start})", source=source) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(what, f"not valid TOML: {err}", source=source) from None
    except RecursionError:
        raise ConfigError(what, f"not valid TOML here: nested deeper than {MAX_DEPTH} levels",
                          source=source) from None
    check_document(data, source)
    return data


def _walk(data: Any) -> Iterator[tuple[tuple[str | int, ...], Any]]:
    stack: list[tuple[tuple[str | int, ...], Any]] = [((), data)]
    while stack:
        path, value = stack.pop()
        yield path, value
        if isinstance(value, dict):
            stack.extend(((*path, k), v) for k, v in reversed(value.items()))
        elif isinstance(value, list):
            stack.extend(((*path, i), v) for i, v in reversed(list(enumerate(value))))


def check_document(data: Any, source: str | None = None) -> None:
    """No value nested deeper than :data:`MAX_DEPTH`, no NaN or infinite float."""
    for path, value in _walk(data):
        if len(path) > MAX_DEPTH:
            raise ConfigError(dotted(path[:MAX_DEPTH]), f"nested deeper than {MAX_DEPTH} "
                              "levels", source=source)
        if isinstance(value, float) and not math.isfinite(value):
            raise ConfigError(dotted(path), f"must be a finite number, got {value!r}",
                              source=source)
