"""A PDO's or an SDO's values in words and units: names, scales, the reserved codes.

The shipped products' conventions (``canbus.tools.pdo_names`` applies them by product):
a patch's resistance codes are ohms by its LSB with the reserved codes named (short,
saturated, open); a force node's INTEGER16 forces are newtons, 0x8000 "none"; taxel status
bytes, reason codes and the valid-taxel mask are spelled out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import canopen

from canbus import codes, contact_record
from decoder.reasons import reason_name

NO_FORCE = -0x8000
PILLARS, AXES = "zxy", "xyz"
UNSIGNED32 = 0x0007
CIA301_UNITS = {0x1006: "µs", 0x1007: "µs", 0x1017: "ms"}


@dataclass(frozen=True, slots=True)
class NamedValue:
    """One mapped variable of a PDO: a short name, its value in ``unit`` and as text."""

    name: str
    value: float | None
    unit: str
    text: str




def var_size(var: canopen.objectdictionary.ODVariable) -> int | None:
    struct = canopen.objectdictionary.ODVariable.STRUCT_TYPES.get(int(var.data_type or 0))
    return None if struct is None else int(struct.size)


def resistance_value(name: str, code: int, lsb_ohm: float) -> NamedValue:
    if code == codes.OPEN:
        return NamedValue(name, math.inf, "Ω", f"{name}=open")
    if code == codes.SATURATED:
        return NamedValue(name, math.inf, "Ω", f"{name}=saturated")
    if code == codes.SHORT:
        return NamedValue(name, 0.0, "Ω", f"{name}=short")
    ohm = code * lsb_ohm
    return NamedValue(name, ohm, "Ω", f"{name}={ohm:.2f} Ω")


def force_value(name: str, value: float) -> NamedValue:
    if int(value) == NO_FORCE:
        return NamedValue(name, None, "N", f"{name}=none")
    return NamedValue(name, value / 1000.0, "N", f"{name}={value / 1000.0:+.3f} N")


def valid_taxels_value(value: float) -> NamedValue:
    bits = int(value)
    valid = bin(bits & 0x1FF).count("1")
    complete = "" if bits & 0x8000 else " incomplete"
    return NamedValue("valid", value, "", f"valid={valid}/9{complete}")


def scaled_value(name: str, factor: float, unit: str, value: float) -> NamedValue:
    scaled = value * factor
    number = f"{int(scaled)}" if float(scaled).is_integer() else f"{scaled:g}"
    return NamedValue(name, scaled, unit, f"{name}={number}{' ' + unit if unit else ''}")


def status_value(name: str, status: int) -> NamedValue:
    faults = [f"{p} {codes.FAULT_NAMES[(status >> (2 * k)) & 3]}"
              for k, p in enumerate(PILLARS) if (status >> (2 * k)) & 3]
    return NamedValue(name, float(status), "", f"{name}={'ok' if not faults else ','.join(faults)}")


def reason_value(name: str, code: int) -> NamedValue:
    """A force node's 0x2004: the decoder's reason code for the taxel (0 OK)."""
    text = "ok" if code == 0 else reason_name(code)
    return NamedValue(name, float(code), "", f"{name}={text}")


def describe_taxel_fault(taxel: int, status: int) -> str:
    """The manufacturer bytes of a patch EMCY (taxel, status byte) in words."""
    return f"taxel {taxel}: {status_value('', status).text.removeprefix('=')}"


def contact_value(sub: int, value: float) -> NamedValue:
    """A force node's 0x2008 sub-index ``sub`` (:mod:`canbus.contact_record`)."""
    return NamedValue(*contact_record.describe(sub, int(value)))


def counted_value(name: str, factor: float, digits: int, unit: str, value: float) -> NamedValue:
    """A count of a small unit in SI, every digit the count has and no more."""
    scaled = value * factor
    number = f"{scaled:.{digits}f}".rstrip("0").rstrip(".") if digits else f"{int(scaled)}"
    return NamedValue(name, scaled, unit, f"{name}={number}{' ' + unit if unit else ''}")
