"""The effects pipeline's stages, each computed only when a scene lists it.

``EFFECTS`` is also the order in which they act: on the force
(elastic_crosstalk), on q = R/R0 - 1 (hysteresis, drift), on the measurement
(readout), on the reported value (noise, faults).
"""

from __future__ import annotations

from sim.effects.crosstalk import CrosstalkParams
from sim.effects.drift import DriftParams
from sim.effects.faults import FaultsParams
from sim.effects.hysteresis import HysteresisParams
from sim.effects.noise import NoiseParams
from sim.effects.readout import ReadoutParams

EFFECT_PARAMS: dict[str, type] = {
    "elastic_crosstalk": CrosstalkParams,
    "hysteresis": HysteresisParams,
    "drift": DriftParams,
    "readout": ReadoutParams,
    "noise": NoiseParams,
    "faults": FaultsParams,
}
EFFECTS = tuple(EFFECT_PARAMS)

__all__ = ["EFFECTS", "EFFECT_PARAMS"]
