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

The range a real patch can have (:data:`CONSTANT_RANGES`, :data:`R0_RANGE_OHM`): the one
statement of the limits. Every constant built here, every value a patch node stores or a
master writes (``canbus.patch_constants``, eds/skin-patch.eds's LowLimit/HighLimit) and
every value a patch reports to the host is held to it; outside it, the value is refused:

* E 10 kPa..1 GPa: the softest silicone that still stands as a pillar (gels are below)
  up to a rigid plastic; rubbers, filled or not, lie between 0.1 and 100 MPa.
* ρ 10 µΩ·m..1 kΩ·m: silver-filled silicones to the least conductive carbon-black ones;
  above, the compound is an antistatic insulator.
* L 0.1..100 mm, S 0.01..1000 mm², taxel pitch 1..100 mm: a skin's pillars and taxels,
  a decade and more either side of the paper's 10 mm, 4 mm² and 15 mm.
* max strain 1..90 %: below 1 % the pillar barely changes its resistance; an elastomer
  pillar collapses before 90 % (the model's own limit is 20 %).
* full-scale force 10 mN..32.767 N: a force node sends INTEGER16 mN, so no larger full
  scale could be published; below 10 counts it is not resolved.
* resistance LSB 100 µΩ..1 kΩ, R0 0.1 Ω..1 MΩ: a 16-bit ohmmeter's full scale from
  6.5 Ω to 65 MΩ; a pillar below 0.1 Ω is a short, above 1 MΩ an open contact.
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
            number(getattr(self, name), name, low, high)
        integer(self.adc_bits, "adc_bits", 8, 32)
        low, high = R0_RANGE_OHM
        r0 = self.nominal_resistance_ohm
        if not (low <= r0.min() and r0.max() <= high):
            raise _error("resistivity_ohm_m", f"{self.resistivity_ohm_m!r} Ω·m over pillars of "
                         f"{self.length_m!r} m and {self.area_m2!r} m² gives R0 "
                         f"{r0.min():g}..{r0.max():g} Ω, outside {low:g}..{high:g} Ω")

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
        from skin.inputs.fields import known_keys

        if not isinstance(data, Mapping):
            raise ConfigError(where, f"must be a table of sensor constants, got "
                              f"{type(data).__name__}")
        known_keys(data, cls.__dataclass_fields__, where, what="sensor constant")
        try:
            return cls(**data)
        except ConfigError as err:
            raise ConfigError(f"{where}.{err.field}", err.problem) from err


CONSTANT_RANGES: dict[str, tuple[float, float]] = {
    "youngs_modulus_pa": (1e4, 1e9), "resistivity_ohm_m": (1e-5, 1e3),
    "length_m": (1e-4, 0.1), "area_m2": (1e-8, 1e-3), "max_strain": (0.01, 0.9),
    "resistance_lsb_ohm": (1e-4, 1e3), "full_scale_force_N": (0.01, 32.767),
    "taxel_pitch_m": (1e-3, 0.1),
}
"""(lowest, highest) of every float constant a real patch can have, SI (module docstring)."""
R0_RANGE_OHM = (0.1, 1e6)
"""(lowest, highest) of a pillar's rest resistance R0 a real patch can have."""


def _error(field: str, problem: str) -> Exception:
    from skin.errors import ConfigError

    return ConfigError(field, problem)


DEFAULT_CONSTANTS = SensorConstants()
