"""The physical stages for the patches that must be computed step by step.

force -> elastic_crosstalk -> tripod forward (q) -> hysteresis -> drift ->
R = R0·(1 + q) -> readout. Noise and faults act later, on every patch's
reported value (see sim.simulator).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from sim.effects.crosstalk import CrosstalkParams, apply_crosstalk
from sim.effects.drift import Drift, DriftParams
from sim.effects.hysteresis import Hysteresis, HysteresisParams
from sim.effects.readout import ReadoutParams, make_readout
from sim.rng import stream
from sim.scene import Scene
from skin.constants import SensorConstants
from skin.tripod import ratio_change_from_force

F64 = NDArray[np.float64]


class Pipeline:
    """Pillar resistances as read out, for ``patches`` computed patches."""

    def __init__(self, scene: Scene, constants: SensorConstants, seed: int, patches: int) -> None:
        effects = scene.effects
        self.constants = constants
        self.r0 = constants.nominal_resistance_ohm
        self.crosstalk = (
            scene.crosstalk_matrix()
            if isinstance(effects.get("elastic_crosstalk"), CrosstalkParams) else None
        )
        h = effects.get("hysteresis")
        self.hysteresis = (
            Hysteresis(h, (patches, 9, 3)) if isinstance(h, HysteresisParams) else None
        )
        d = effects.get("drift")
        self.drift = (
            Drift(d, patches, scene.rate_hz, stream(seed, "drift"))
            if isinstance(d, DriftParams) else None
        )
        r = effects.get("readout")
        self.readout: Callable[[F64], F64] | None = (
            make_readout(r, constants) if isinstance(r, ReadoutParams) else None
        )

    def resistance(self, force_N: F64, time_s: F64) -> F64:
        """(n, patches, 9, 3) true force -> (n, patches, 9, 3) measured pillar resistances.

        Raises StrainLimitError from the tripod model.
        """
        if self.crosstalk is not None:
            force_N = apply_crosstalk(self.crosstalk, force_N)
        q = ratio_change_from_force(force_N, self.constants)
        if self.hysteresis is not None:
            q = self.hysteresis.apply(q)
        if self.drift is not None:
            q = self.drift.apply(q, time_s)
        q += 1.0
        q *= self.r0
        return q if self.readout is None else self.readout(q)

    def baseline(self) -> F64:
        """(9, 3) measured resistances of an unloaded patch (stateless stages only)."""
        r: F64 = np.broadcast_to(self.r0, (1, 9, 3)).copy()
        if self.readout is not None:
            r = self.readout(r)
        first: F64 = r[0]
        return first
