"""Typed parameter tables: TOML table -> frozen dataclass, every error naming its field."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, Protocol, TypeVar

from skin.errors import ConfigError


class Params(Protocol):
    """A frozen dataclass of parameters that checks its own values."""

    def check(self, where: str) -> None: ...


P = TypeVar("P", bound=Params)


def _coerce(value: object, annotation: str, field: str) -> object:
    optional = annotation.endswith("| None")
    base = annotation.removesuffix("| None").strip()
    if value is None and optional:
        return None
    if base == "float" and isinstance(value, int | float) and not isinstance(value, bool):
        if not math.isfinite(value):
            raise ConfigError(field, f"must be a finite number, got {value!r}")
        return float(value)
    if base == "int" and isinstance(value, int) and not isinstance(value, bool):
        return value
    if base == "str" and isinstance(value, str):
        return value
    if base == "bool" and isinstance(value, bool):
        return value
    raise ConfigError(field, f"must be {base}, got {type(value).__name__} {value!r}")


def check_keys(table: Mapping[str, object], known: set[str] | list[str], where: str) -> None:
    """Raise ConfigError naming the first unknown key of ``table``."""
    for key in table:
        if key not in known:
            listed = ", ".join(sorted(known)) or "none"
            raise ConfigError(f"{where}.{key}", f"unknown key; known: {listed}")


def build(cls: type[P], table: Mapping[str, Any], where: str) -> P:
    """Build the parameter dataclass ``cls`` from ``table``; defaults fill the rest."""
    names = {f.name: str(f.type) for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    check_keys(table, set(names), where)
    kwargs = {key: _coerce(value, names[key], f"{where}.{key}") for key, value in table.items()}
    params = cls(**kwargs)
    params.check(where)
    return params


def positive(value: float, field: str) -> None:
    if not value > 0:
        raise ConfigError(field, f"must be > 0, got {value!r}")


def non_negative(value: float, field: str) -> None:
    if not value >= 0:
        raise ConfigError(field, f"must be >= 0, got {value!r}")


def one_of(value: str, known: tuple[str, ...], field: str, what: str) -> None:
    if value not in known:
        raise ConfigError(field, f"unknown {what} {value!r}; known: {', '.join(known)}")
