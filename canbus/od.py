"""Find the shipped EDS files and load object dictionaries with ``canopen.import_od``."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from importlib import resources
from pathlib import Path

import canopen

from canbus.busopen import reason
from canbus.edsfile import check_loadable
from skin.errors import ConfigError
from skin.inputs import fields

SHIPPED = ("skin-patch", "skin-forces")
"""EDS files inside the ``eds`` package, found by name after any install."""


@contextmanager
def eds_file(name_or_path: str | os.PathLike[str]) -> Iterator[Path]:
    """A path to a shipped EDS (``"skin-patch"``) or to an existing EDS file.

    The path is valid inside the ``with`` block: from a zipped install, importlib.resources
    extracts the shipped file to a temporary one that it removes on exit.
    """
    text = os.fspath(name_or_path)
    stem = text.removesuffix(".eds")
    if stem in SHIPPED:
        with resources.as_file(resources.files("eds").joinpath(f"{stem}.eds")) as path:
            yield Path(path)
        return
    path = Path(text)
    if not path.is_file():
        raise ConfigError("eds", f"no shipped EDS {text!r} (have {', '.join(SHIPPED)}) "
                          "and no such file")
    yield path


def load_od(name_or_path: str | os.PathLike[str], node_id: int) -> canopen.ObjectDictionary:
    """The object dictionary of an EDS, with ``$NODEID`` resolved to ``node_id``.

    A file (not a shipped EDS) is checked first (:func:`canbus.edsfile.check_loadable`):
    anything canopen would fail on, or silently drop, is a ConfigError naming the file,
    the section and the key; whatever canopen still raises is turned into one too.
    """
    fields.node_id(node_id, "node_id")
    with eds_file(name_or_path) as path:
        if os.fspath(name_or_path).removesuffix(".eds") not in SHIPPED:
            check_loadable(path)
        try:
            return canopen.import_od(str(path), node_id)
        except Exception as err:  # canopen's parser raises whatever it meets
            raise ConfigError("", f"canopen cannot load it: {reason(err)}",
                              source=os.fspath(path)) from err
