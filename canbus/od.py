"""Find the shipped EDS files and load object dictionaries with ``canopen.import_od``."""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

import canopen

from skin.errors import ConfigError

SHIPPED = ("skin-patch", "skin-forces")
"""EDS files inside the ``eds`` package, found by name after any install."""


def eds_path(name_or_path: str | os.PathLike[str]) -> Path:
    """The path of a shipped EDS (``"skin-patch"``) or of an existing EDS file."""
    text = os.fspath(name_or_path)
    stem = text.removesuffix(".eds")
    if stem in SHIPPED:
        with resources.as_file(resources.files("eds").joinpath(f"{stem}.eds")) as path:
            return Path(path)
    path = Path(text)
    if not path.is_file():
        raise ConfigError("eds", f"no shipped EDS {text!r} (have {', '.join(SHIPPED)}) "
                          "and no such file")
    return path


def load_od(name_or_path: str | os.PathLike[str], node_id: int) -> canopen.ObjectDictionary:
    """The object dictionary of an EDS, with ``$NODEID`` resolved to ``node_id``."""
    if not 1 <= node_id <= 127:
        raise ConfigError("node_id", f"must be in 1..127, got {node_id}")
    return canopen.import_od(str(eds_path(name_or_path)), node_id)
