"""Sensor constants: one frozen dataclass, SI units inside.

Defaults, and why:

* ``length_m = 10 mm`` and ``area_m2 = 4 mm²`` are the paper's (section 2.1).
* ``youngs_modulus_pa = 25 MPa``: a stiff, highly filled conductive silicone.
  E·S = 100 N, so the paper's full-scale 5 N press strains pillar z by 5.7 %,
  well inside the paper's 20 % limit and half the load (9.95 N) at which the
  tripod snaps through. Softer rubbers (8-12 MPa) snap through below 5 N.
* ``resistivity_ohm_m = 0.4 Ω·m``: typical of carbon-black silicone; it gives
  the vertical pillar R0 = ρ·L/S = 1 kΩ and the diagonal pillars √2 kΩ.
* ``resistance_lsb_ohm = 0.05 Ω``: the UNSIGNED16 code the patch sends; full
  scale 65535 · 0.05 = 3276.75 Ω covers the 20 %-stretched diagonal pillar
  (1.44 · 1414 Ω = 2036 Ω) with margin. Code 0xFFFF means over-range/open.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

PILLARS = ("z", "x", "y")
"""Pillar order everywhere: z (paper "1"), x (paper "4"), y (paper "6")."""

AXES = ("Fx", "Fy", "Fz")
"""Force component order everywhere. Fz > 0 presses into the skin."""

TAXELS_PER_PATCH = 9
GRID = (3, 3)


@dataclass(frozen=True)
class SensorConstants:
    """Every physical constant of one taxel design."""

    youngs_modulus_pa: float = 25.0e6
    resistivity_ohm_m: float = 0.4
    length_m: float = 10.0e-3
    area_m2: float = 4.0e-6
    max_strain: float = 0.20
    resistance_lsb_ohm: float = 0.05
    adc_bits: int = 16
    full_scale_force_N: float = 5.0
    taxel_pitch_m: float = 15.0e-3

    def __post_init__(self) -> None:
        from skin.inputs.fields import integer, number

        for name, (low, high) in CONSTANT_RANGES.items():
            number(getattr(self, name), name, high=high, above=low)
        if not self.max_strain < 1:
            raise _error("max_strain", f"must be in (0, 1), got {self.max_strain!r}")
        integer(self.adc_bits, "adc_bits", 8, 32)

    @property
    def axial_stiffness_N(self) -> float:
        """E·S: the force that would double a pillar's length (linear Hooke)."""
        return self.youngs_modulus_pa * self.area_m2

    @property
    def rest_lengths_m(self) -> NDArray[np.float64]:
        """Rest length of pillars (z, x, y)."""
        L = self.length_m
        return np.array([L, math.sqrt(2.0) * L, math.sqrt(2.0) * L])

    @property
    def nominal_resistance_ohm(self) -> NDArray[np.float64]:
        """R0 = ρ·l/S of pillars (z, x, y) (Eq. 1 with V = S·l)."""
        return self.resistivity_ohm_m * self.rest_lengths_m / self.area_m2

    @property
    def adc_full_scale_code(self) -> int:
        return int(2**self.adc_bits - 1)

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "sensor") -> SensorConstants:
        """The constants of a parsed table (a model file's, a dataset's, a config's); a
        ConfigError names ``where.<constant>``."""
        from skin.errors import ConfigError

        if not isinstance(data, Mapping):
            raise ConfigError(where, f"must be a table of sensor constants, got "
                              f"{type(data).__name__}")
        known = set(cls.__dataclass_fields__)
        for key in data:
            if key not in known:
                raise ConfigError(f"{where}.{key}", "unknown sensor constant; known: "
                                  f"{', '.join(sorted(known))}")
        try:
            return cls(**data)
        except ConfigError as err:
            raise ConfigError(f"{where}.{err.field}", err.problem) from err


CONSTANT_RANGES: dict[str, tuple[float, float]] = {
    "youngs_modulus_pa": (0.0, 1e12), "resistivity_ohm_m": (0.0, 1e9),
    "length_m": (0.0, 1.0), "area_m2": (0.0, 1.0), "max_strain": (0.0, 1.0),
    "resistance_lsb_ohm": (0.0, 1e6), "full_scale_force_N": (0.0, 1e4),
    "taxel_pitch_m": (0.0, 1.0),
}
"""(above, at most) of every float constant: each must be more than the first."""


def _error(field: str, problem: str) -> Exception:
    from skin.errors import ConfigError

    return ConfigError(field, problem)


DEFAULT_CONSTANTS = SensorConstants()
