"""Decoder names -> classes, imported lazily; extended by the ``canskin.decoders`` entry points.

Mirrors python-can's ``BACKENDS``: built-in decoders are ``"module:Class"``
strings imported on first use, and any installed distribution can add one::

    [project.entry-points."canskin.decoders"]
    my-decoder = "my_package.module:MyDecoder"

The entry points are read once, on first use, and each class is imported once; ``refresh()``
reads them again.
"""

from __future__ import annotations

import functools
import importlib
import os
from collections.abc import Mapping
from importlib.metadata import entry_points
from types import MappingProxyType
from typing import Any

from decoder.modelfile import read_model
from decoder.protocol import BaseDecoder, Decoder
from skin.errors import ConfigError, ModelFileError

ENTRY_POINT_GROUP = "canskin.decoders"

BUILTIN_DECODERS: dict[str, str] = {
    "analytic": "decoder.analytic:AnalyticDecoder",
    "deconv": "decoder.deconv:DeconvDecoder",
    "lm-mlp": "decoder.lmmlp:LMMLPDecoder",
    "hybrid": "decoder.hybrid:HybridDecoder",
    "eq9": "decoder.eq9:Eq9Decoder",
}


@functools.cache
def _registry() -> Mapping[str, str]:
    """Names -> "module:Class", the entry points read once (:func:`refresh` reads them again)."""
    names = dict(BUILTIN_DECODERS)
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        names.setdefault(ep.name, ep.value)
    return MappingProxyType(names)


def refresh() -> None:
    """Forget the decoders resolved so far and read the entry points again (after a
    distribution that registers decoders was installed into this process)."""
    _registry.cache_clear()
    _import_class.cache_clear()


def available_decoders() -> tuple[str, ...]:
    """Every registered decoder name, built-in first."""
    names = _registry()
    extra = sorted(n for n in names if n not in BUILTIN_DECODERS)
    return (*BUILTIN_DECODERS, *extra)


def decoder_class(name: str) -> type[Decoder]:
    """The class registered under ``name``, imported on first use."""
    names = _registry()
    if name not in names:
        raise ConfigError("decoder", f"unknown decoder {name!r}; known: {', '.join(names)}")
    return _import_class(names[name])


@functools.cache
def _import_class(target: str) -> type[Decoder]:
    module_name, _, attr = target.partition(":")
    cls: type[Decoder] = getattr(importlib.import_module(module_name), attr)
    return cls


def needs_fitting(cls: type[Decoder]) -> bool:
    """Whether ``cls`` decodes only once fitted (or loaded from a model file): the class's
    ``needs_fitting``; a plug-in that does not say is taken to need it."""
    return bool(getattr(cls, "needs_fitting", True))


def create_decoder(name: str, **params: Any) -> Decoder:
    """An unfitted decoder ``name`` built with keyword parameters."""
    return decoder_class(name)(**params)


def load_decoder(path: str | os.PathLike[str]) -> Decoder:
    """Load any model file, choosing the class by the name stored in it."""
    content = read_model(path)
    try:
        cls = decoder_class(content.name)
    except ConfigError as err:
        raise ModelFileError(f"{os.fspath(path)}: name: {err.problem}") from err
    if issubclass(cls, BaseDecoder):
        return cls.from_content(content.params, content.state, os.fspath(path),
                                version=content.version, meta=content.meta)
    return cls.load(path)
