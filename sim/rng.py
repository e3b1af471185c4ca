"""Independent random streams: one generator per (seed, component name).

Each component (a load, the noise, the drift) draws from its own stream, so
listing one more effect in a scene never changes the draws of another.
"""

from __future__ import annotations

import zlib

import numpy as np


def stream(seed: int, name: str, *index: int) -> np.random.Generator:
    """The generator of component ``name`` (optionally sub-indexed) for ``seed``."""
    key = (zlib.crc32(name.encode("utf-8")), *index)
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed, spawn_key=key)))
