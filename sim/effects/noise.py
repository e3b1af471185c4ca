"""noise: Gaussian read noise, then the node's ADC.

The ADC reports code = round(R / lsb) on ``adc_bits`` bits; the top code
2**adc_bits - 1 means over-range or open circuit, and the reported resistance
is code * lsb. This is the only place values saturate.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from sim.params import non_negative
from skin.constants import SensorConstants

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class NoiseParams:
    sigma_rel: float = 0.0005

    RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "sigma_rel": (0.0, 1.0)}

    def check(self, where: str) -> None:
        non_negative(self.sigma_rel, f"{where}.sigma_rel")


def quantise(r_ohm: F64, constants: SensorConstants) -> F64:
    """In place: R -> ADC code * lsb, over-range (and +inf) to the full-scale code."""
    lsb = constants.resistance_lsb_ohm
    full = float(constants.adc_full_scale_code)
    with np.errstate(invalid="ignore"):
        np.divide(r_ohm, lsb, out=r_ohm)
        np.rint(r_ohm, out=r_ohm)
        np.clip(r_ohm, 0.0, full, out=r_ohm)
    r_ohm[np.isnan(r_ohm)] = full
    np.multiply(r_ohm, lsb, out=r_ohm)
    return r_ohm


class Noise:
    def __init__(
        self, p: NoiseParams, constants: SensorConstants, pillars: int, rng: np.random.Generator
    ) -> None:
        self.sigma_ohm = p.sigma_rel * constants.nominal_resistance_ohm[:pillars]
        self.constants, self.rng = constants, rng

    def apply(self, r_ohm: F64) -> F64:
        """In place on (n, patches, 9, P): add read noise, then quantise."""
        if np.any(self.sigma_ohm > 0):
            r_ohm += self.rng.standard_normal(r_ohm.shape) * self.sigma_ohm
        return quantise(r_ohm, self.constants)
