"""Decoder names -> classes, imported lazily; extended by the ``canskin.decoders`` entry points.

Mirrors python-can's ``BACKENDS``: built-in decoders are ``"module:Class"``
strings imported on first use, and any installed distribution can add one::

    [project.entry-points."canskin.decoders"]
    my-decoder = "my_package.module:MyDecoder"
"""

from __future__ import annotations

import importlib
import os
from importlib.metadata import entry_points
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


def _registry() -> dict[str, str]:
    names = dict(BUILTIN_DECODERS)
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        names.setdefault(ep.name, ep.value)
    return names


def available_decoders() -> tuple[str, ...]:
    """Every registered decoder name, built-in first."""
    names = _registry()
    extra = sorted(n for n in names if n not in BUILTIN_DECODERS)
    return (*BUILTIN_DECODERS, *extra)


def decoder_class(name: str) -> type[Decoder]:
    """Import and return the class registered under ``name``."""
    names = _registry()
    if name not in names:
        raise ConfigError("decoder", f"unknown decoder {name!r}; known: {', '.join(names)}")
    module_name, _, attr = names[name].partition(":")
    module = importlib.import_module(module_name)
    cls: type[Decoder] = getattr(module, attr)
    return cls


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
