"""Typed parameter tables: TOML table -> frozen dataclass, every error naming its field.

Each parameter dataclass may declare ``RANGES``: ``{field: (low, high)}``, the closed
interval of a number field, checked by :func:`build` before the class's own ``check``
(docs/cli.md lists them): a value far outside what the physics means (a coupling of
1e300) is refused naming its own field, never found later as an overflow elsewhere.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any, Protocol, TypeVar

from skin.errors import ConfigError
from skin.inputs import fields


class Params(Protocol):
    """A frozen dataclass of parameters that checks its own values."""

    def check(self, where: str) -> None: ...


P = TypeVar("P", bound=Params)


_KINDS = {"float": float, "int": int, "str": str, "bool": bool}


def _coerce(value: object, name: str, annotation: str, field: str,
            limits: tuple[float, float] | None) -> object:
    optional = annotation.endswith("| None")
    base = annotation.removesuffix("| None").strip()
    if value is None and optional:
        return None
    if name == "node_id" and base == "int":
        return fields.node_id(value, field)
    kind = _KINDS.get(base)
    if kind is None:
        raise ConfigError(field, f"must be {base}, got {fields.shown(value)}")
    low, high = limits if limits is not None else (None, None)
    return fields.typed(value, kind, field, low, high)


def build(cls: type[P], table: Mapping[str, Any], where: str) -> P:
    """Build the parameter dataclass ``cls`` from ``table``; defaults fill the rest. A
    field named ``node_id`` is a CANopen node-ID (:func:`skin.inputs.fields.node_id`)."""
    names = {f.name: str(f.type) for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    fields.known_keys(table, names, where)
    ranges: dict[str, tuple[float, float]] = getattr(cls, "RANGES", {})
    kwargs = {key: _coerce(value, key, names[key], f"{where}.{key}", ranges.get(key))
              for key, value in table.items()}
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
