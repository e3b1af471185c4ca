"""The host's decoders: one object per decoder, model file and sensor constants, shared by
every patch that uses it (one batched decode call), built once and warmed up off the
data path.

A model file is read once, by the config check (``PatchConfig.prototype``); a decoder
without one is built from the registry with the constants the patch reports.
"""

from __future__ import annotations

import os
import threading

import numpy as np
from numpy.typing import NDArray

from canbus.master.hostconfig import PatchConfig
from canbus.master.patch_setup import PatchSetup
from decoder.protocol import BaseDecoder, Decoder
from decoder.registry import create_decoder, load_decoder
from skin.constants import TAXELS_PER_PATCH

_Key = tuple[str, str, object]


class DecoderCache:
    """Decoders by (name, model file, constants); thread-safe."""

    def __init__(self) -> None:
        self._decoders: dict[_Key, Decoder] = {}
        self._warm: set[tuple[_Key, int]] = set()
        self._lock = threading.Lock()

    def get(self, config: PatchConfig, setup: PatchSetup) -> tuple[Decoder, NDArray[np.float64]]:
        """The decoder of a patch and its zero-force resistances ``(9, P)``."""
        constants = setup.info.constants
        key = (config.decoder, os.fspath(config.model or ""),
               constants if config.model is None else None)
        with self._lock:
            decoder = self._decoders.get(key)
            if decoder is None:
                decoder = self._decoders[key] = _build(config, constants)
        pillars = setup.pillars
        if isinstance(decoder, BaseDecoder):
            r0 = decoder.r0_for(pillars)
        else:
            r0 = constants.nominal_resistance_ohm[:pillars]
        r0_ref = np.broadcast_to(r0, (TAXELS_PER_PATCH, pillars)).astype(np.float64)
        with self._lock:
            warm = (key, pillars) in self._warm
        if not warm:
            # A decoder may build tables on its first call (analytic z: the exact inverse
            # table): here, on a set-up thread, not in the data plane's first cycle.
            decoder.decode(r0_ref[None])
            with self._lock:
                self._warm.add((key, pillars))
        return decoder, r0_ref


def _build(config: PatchConfig, constants: object) -> Decoder:
    if config.prototype is not None:
        return config.prototype
    if config.model is not None:  # a config that was not checked
        return load_decoder(config.model)
    try:
        return create_decoder(config.decoder, constants=constants)
    except TypeError:  # a plug-in decoder without sensor constants
        return create_decoder(config.decoder)
