"""How a patch's physical constants travel: scaled integers with the unit in the name.

A REAL32 default in an EDS reads differently by reader (lely's tools take it as the
float's bit pattern, python-canopen as a decimal), so eds/skin-patch.eds holds every
physical constant as an UNSIGNED32 count of a small unit, named in the object's name:

| object | name | unit | 1 count |
|---|---|---|---|
| 0x2001 | Resistance LSB (uOhm) | µΩ | 1e-6 Ω |
| 0x2002 sub 1..27 | R0 taxel T pillar P (mOhm) | mΩ | 1e-3 Ω |
| 0x2003 sub 1 | Young's modulus (Pa) | Pa | 1 Pa |
| 0x2003 sub 2 | Resistivity (uOhm m) | µΩ·m | 1e-6 Ω·m |
| 0x2003 sub 3 | Pillar length (um) | µm | 1e-6 m |
| 0x2003 sub 4 | Pillar cross-section (um2) | µm² | 1e-12 m² |
| 0x2003 sub 5 | Max strain (ppm) | ppm | 1e-6 |
| 0x2003 sub 6 | Full-scale force (mN) | mN | 1e-3 N |
| 0x2003 sub 7 | Taxel pitch (um) | µm | 1e-6 m |

Each object holds only the range a real patch can have (``skin.constants.CONSTANT_RANGES``
and ``R0_RANGE_OHM``, which say why), in its counts: :attr:`Scaled.count_range`, the
LowLimit/HighLimit of eds/skin-patch.eds. A value outside is refused where it is written
(:meth:`Scaled.to_count`, a ConfigError) and where it is reported (:meth:`Scaled.refusal`).

Every side (the patch node, the host's set-up, ``skin calibrate --write-node``, the sniffer,
the recorded-dataset path) converts with the functions here, so all read the same number.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

from skin.constants import CONSTANT_RANGES, R0_RANGE_OHM, SensorConstants
from skin.errors import ConfigError

LSB, NOMINAL, CONSTANTS = 0x2001, 0x2002, 0x2003
U32_MAX = 0xFFFF_FFFF
_U32 = struct.Struct("<I")


@dataclass(frozen=True)
class Scaled:
    """One constant on the wire: SI value = count x ``si_per_count``, held to ``low..high``
    (SI), the range a real patch can have."""

    field: str
    si_per_count: float
    unit: str
    """The unit of one count, as in the object's name."""
    si_unit: str
    name: str
    """What the object is, for a reason that names it."""
    low: float
    high: float

    @property
    def count_range(self) -> tuple[int, int]:
        """``low..high`` in counts: the object's LowLimit and HighLimit."""
        return self.count_of(self.low), self.count_of(self.high)

    def count_of(self, value: float) -> int:
        """The count nearest to ``value`` (SI), unchecked."""
        return round(value / self.si_per_count)

    def to_count(self, value: float) -> int:
        """The count nearest to ``value`` (SI); a ConfigError if it is not finite or outside
        the range a real patch can have."""
        if not math.isfinite(value):
            raise ConfigError(self.field, f"must be finite, got {value!r}")
        count = self.count_of(value)
        low, high = self.count_range
        if not low <= count <= high:
            raise ConfigError(self.field, f"{value!r} {self.si_unit} is outside "
                                          f"{self.shown_range()}, the range a real patch has")
        return count

    def to_si(self, count: int) -> float:
        return count * self.si_per_count if self.si_per_count >= 1 else \
            count / round(1 / self.si_per_count)

    def quantised(self, value: float) -> float:
        """``value`` as it reads back from the patch."""
        return self.to_si(self.to_count(value))

    def refusal(self, where: str, count: int, name: str = "") -> str | None:
        """Why a patch that reports ``count`` at ``where`` (e.g. ``0x2003 sub 1``) is refused,
        naming the object (``name``, default the scale's), the value and the range (None:
        inside the range)."""
        low, high = self.count_range
        if low <= count <= high:
            return None
        return f"{where} ({name or self.name}) = {self._shown(count)}: outside " \
               f"{self.shown_range()}, the range a real patch has"

    def shown_range(self) -> str:
        low, high = self.count_range
        si = "" if self.unit == self.si_unit else \
            f" ({self.low:g}..{self.high:g}{' ' + self.si_unit if self.si_unit else ''})"
        return f"{low}..{high} {self.unit}{si}"

    def _shown(self, count: int) -> str:
        si = "" if self.unit == self.si_unit else \
            f" ({self.to_si(count):g}{' ' + self.si_unit if self.si_unit else ''})"
        return f"{count} {self.unit}{si}"


def _scaled(field: str, si_per_count: float, unit: str, si_unit: str, name: str) -> Scaled:
    low, high = R0_RANGE_OHM if field == "r0_ohm" else CONSTANT_RANGES[field]
    return Scaled(field, si_per_count, unit, si_unit, name, low, high)


LSB_SCALE = _scaled("resistance_lsb_ohm", 1e-6, "uOhm", "Ω", "resistance LSB")
R0_SCALE = _scaled("r0_ohm", 1e-3, "mOhm", "Ω", "R0")
CONSTANT_SCALES = (
    _scaled("youngs_modulus_pa", 1.0, "Pa", "Pa", "Young's modulus"),
    _scaled("resistivity_ohm_m", 1e-6, "uOhm m", "Ω·m", "resistivity"),
    _scaled("length_m", 1e-6, "um", "m", "pillar length"),
    _scaled("area_m2", 1e-12, "um2", "m²", "pillar cross-section"),
    _scaled("max_strain", 1e-6, "ppm", "", "max strain"),
    _scaled("full_scale_force_N", 1e-3, "mN", "N", "full-scale force"),
    _scaled("taxel_pitch_m", 1e-6, "um", "m", "taxel pitch"),
)
"""0x2003 sub-indexes 1..7, in order."""
CONSTANT_FIELDS = tuple(s.field for s in CONSTANT_SCALES)


def scale_of(index: int, subindex: int) -> Scaled | None:
    """The scale of a patch object (None: not a scaled constant)."""
    if index == LSB and subindex == 0:
        return LSB_SCALE
    if index == NOMINAL and 1 <= subindex <= 27:
        return R0_SCALE
    if index == CONSTANTS and 1 <= subindex <= len(CONSTANT_SCALES):
        return CONSTANT_SCALES[subindex - 1]
    return None


def decode_si(index: int, subindex: int, raw: bytes) -> float | None:
    """The SI value of an SDO payload of a scaled object (None: not one, or too short)."""
    scale = scale_of(index, subindex)
    if scale is None or len(raw) < 4:
        return None
    return scale.to_si(_U32.unpack_from(raw)[0])


def encode_si(index: int, subindex: int, value: float) -> bytes:
    """The SDO payload that writes ``value`` (SI) to a scaled object."""
    scale = scale_of(index, subindex)
    if scale is None:
        raise KeyError(f"0x{index:04X}:{subindex:02X} is not a scaled patch constant")
    return _U32.pack(scale.to_count(value))


def constant_counts(constants: SensorConstants) -> list[int]:
    """0x2003 sub 1..7 of a patch holding ``constants``."""
    return [s.to_count(float(getattr(constants, s.field))) for s in CONSTANT_SCALES]


def reported_refusal(lsb_count: int, counts: Sequence[int]) -> str | None:
    """Why a patch reporting ``lsb_count`` (0x2001) and ``counts`` (0x2003 sub 1..7) is
    refused: its first object outside the range a real patch can have (None: none is)."""
    reasons = [LSB_SCALE.refusal(f"0x{LSB:04X}", lsb_count)]
    reasons += [s.refusal(f"0x{CONSTANTS:04X} sub {k}", int(c))
                for k, (s, c) in enumerate(zip(CONSTANT_SCALES, counts, strict=True), start=1)]
    return next((r for r in reasons if r is not None), None)


def reported_constants(lsb_count: int, counts: Sequence[int],
                       adc_bits: int = 16) -> SensorConstants:
    """The constants a patch reports by its 0x2001 and 0x2003 sub 1..7 (a ConfigError if one
    is outside its range: :func:`reported_refusal` says which)."""
    values = {s.field: s.to_si(int(c)) for s, c in zip(CONSTANT_SCALES, counts, strict=True)}
    return SensorConstants(resistance_lsb_ohm=LSB_SCALE.to_si(lsb_count), adc_bits=adc_bits,
                           **values)
