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
from dataclasses import asdict, dataclass

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
        from skin.errors import ConfigError

        for name in ("youngs_modulus_pa", "resistivity_ohm_m", "length_m", "area_m2",
                     "resistance_lsb_ohm", "full_scale_force_N", "taxel_pitch_m"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ConfigError(name, f"must be a positive finite number, got {value!r}")
        if not 0 < self.max_strain < 1:
            raise ConfigError("max_strain", f"must be in (0, 1), got {self.max_strain!r}")
        if not 8 <= self.adc_bits <= 32:
            raise ConfigError("adc_bits", f"must be in [8, 32], got {self.adc_bits!r}")

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
    def from_dict(cls, data: dict[str, float]) -> SensorConstants:
        from skin.errors import ConfigError

        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"sensor.{unknown[0]}", "unknown sensor constant")
        return cls(**data)  # type: ignore[arg-type]


DEFAULT_CONSTANTS = SensorConstants()
