"""readout: how the node measures each pillar, from the true pillar resistances.

* ``ideal``: every pillar measured alone.
* ``passive_matrix``: the two-point resistance between the pillar's two wires
  of the whole 27-pillar network, every other wire floating (sneak paths,
  ghosting); see ``sim.effects.network``.
* ``zero_potential``: selected row driven, other rows grounded, columns held at
  the virtual ground of transimpedance amplifiers of finite open-loop gain A:
  R_meas = R·(1 + (1 + R_f·G_column)/A), G_column the conductance on the
  pillar's column wire (its own plus its neighbours').
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from sim.effects.network import LOWER_WIRE, passive_matrix_resistance
from sim.params import one_of, positive
from skin.constants import SensorConstants

F64 = NDArray[np.float64]
READOUTS = ("ideal", "passive_matrix", "zero_potential")


@dataclass(frozen=True)
class ReadoutParams:
    kind: str = "ideal"
    open_loop_gain: float = 1.0e4
    feedback_ohm: float | None = None

    RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "open_loop_gain": (0.0, 1e12), "feedback_ohm": (0.0, 1e12)}

    def check(self, where: str) -> None:
        one_of(self.kind, READOUTS, f"{where}.kind", "readout")
        positive(self.open_loop_gain, f"{where}.open_loop_gain")
        if self.feedback_ohm is not None:
            positive(self.feedback_ohm, f"{where}.feedback_ohm")


def zero_potential_resistance(r_ohm: F64, open_loop_gain: float, feedback_ohm: float) -> F64:
    """Measured resistance (..., 9, 3) under zero-potential scanning."""
    g = 1.0 / r_ohm
    flat = g.reshape(*g.shape[:-2], 27)
    column = np.zeros((*g.shape[:-2], 6))
    for wire in range(6):
        column[..., wire] = flat[..., wire == LOWER_WIRE].sum(axis=-1)
    g_column = column[..., LOWER_WIRE].reshape(r_ohm.shape)
    out: F64 = r_ohm * (1.0 + (1.0 + feedback_ohm * g_column) / open_loop_gain)
    return out


def make_readout(p: ReadoutParams, constants: SensorConstants) -> Callable[[F64], F64] | None:
    """The readout function on (..., 9, 3) resistances; None for ``ideal`` (identity)."""
    if p.kind == "passive_matrix":
        return passive_matrix_resistance
    if p.kind == "zero_potential":
        feedback = p.feedback_ohm
        if feedback is None:
            feedback = float(constants.nominal_resistance_ohm[0])
        gain = p.open_loop_gain
        return lambda r: zero_potential_resistance(r, gain, feedback)
    return None
