"""``skin eds check``: what canopen's lenient EDS parser lets through.

The structural rules need the file's sections as written (canopen's object dictionary
forgets the object lists), so the file is read with the same ``configparser`` setup
canopen uses; it must also load with ``canopen.import_od``. Rules:

1. the [MandatoryObjects], [OptionalObjects], [ManufacturerObjects] lists match their
   ``SupportedObjects`` counts and the object sections, and each ARRAY/RECORD has the
   ``SubNumber`` of sub-objects it claims;
2. the CiA 301 mandatory objects 0x1000, 0x1001, 0x1018 are present;
3. every DataType is a CiA 301 basic type and every AccessType is one of
   ro, wo, rw, rwr, rww, const;
4. every PDO mapping entry names an existing, PDO-mappable object of the mapped size;
5. the entries a PDO maps add up to at most 64 bits;
6. what lely's ``dcfchk`` checks (``canbus.tools.edslint``): CiA 306 keys and sections,
   object lists by range, values that parse as integers of their type and inside the
   limits, and no REAL default that lely and python-canopen read as different numbers.

Before these rules, the file is read and its values checked as
:mod:`canbus.edsfile` does for every EDS canskin loads (parse errors, non-numeric or
out-of-range values, LowLimit above HighLimit, bad ``$NODEID`` expressions, counts):
when a value is unreadable, only those problems are reported (the rules above would
only repeat them), and counts are checked before anything loops over them.
"""

from __future__ import annotations

import configparser
import os
import re

import canopen

from canbus.busopen import reason
from canbus.edsfile import read_eds, reference_problems, value_problems
from canbus.tools.edslint import lint
from skin.errors import ConfigError

LISTS = ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects")
MANDATORY = (0x1000, 0x1001, 0x1018)
ACCESS_TYPES = ("ro", "wo", "rw", "rwr", "rww", "const")
TYPE_BITS = {0x01: 1, 0x02: 8, 0x03: 16, 0x04: 32, 0x05: 8, 0x06: 16, 0x07: 32, 0x08: 32,
             0x09: 0, 0x0A: 0, 0x0B: 0, 0x0C: 48, 0x0D: 48, 0x0F: 0, 0x10: 24, 0x11: 64,
             0x12: 40, 0x13: 48, 0x14: 56, 0x15: 64, 0x16: 24, 0x18: 40, 0x19: 48,
             0x1A: 56, 0x1B: 64}
_OBJECT = re.compile(r"^([0-9A-Fa-f]{4})$")
_SUB = re.compile(r"^([0-9A-Fa-f]{4})sub([0-9A-Fa-f]{1,2})$")
MAX_MAPPED = 0x40
"""A PDO maps at most 64 entries (CiA 301: sub-index 0 of a mapping object, 0..0x40)."""


def _int(text: str) -> int:
    """The number of a value (its ``$NODEID`` term as 0); -1 when it has none."""
    compact = text.replace(" ", "").upper().replace("$NODEID", "0")
    try:
        return sum(int(term, 0) for term in compact.split("+"))
    except ValueError:
        return -1


def check(path: str | os.PathLike[str]) -> list[str]:
    """One line per problem found in the EDS at ``path``; empty when it is valid."""
    try:
        eds = read_eds(path)
    except ConfigError as err:
        return [err.problem]
    problems = value_problems(eds)
    if problems:
        return problems
    objects = {int(m.group(1), 16): s for s in eds.sections() if (m := _OBJECT.match(s))}
    subs: dict[int, dict[int, str]] = {}
    for section in eds.sections():
        if m := _SUB.match(section):
            subs.setdefault(int(m.group(1), 16), {})[int(m.group(2), 16)] = section
    problems += _check_lists(eds, objects)
    problems += [f"mandatory object 0x{i:04X} is missing" for i in MANDATORY if i not in objects]
    for index, section in sorted(objects.items()):
        problems += _check_object(eds, index, section, subs.get(index, {}))
    for index in sorted(i for i in objects if 0x1600 <= i <= 0x17FF or 0x1A00 <= i <= 0x1BFF):
        problems += _check_mapping(eds, index, subs.get(index, {}))
    mentioned = {p.split("]")[0] for p in problems if p.startswith("[")}
    problems += [p for p in reference_problems(eds) if p.split("]")[0] not in mentioned]
    mentioned = {p.split("]")[0] for p in problems if p.startswith("[")}
    problems += [p for p in lint(eds) if p.split("]")[0] not in mentioned]
    if not problems:
        try:
            canopen.import_od(os.fspath(path), 1)
        except Exception as err:  # canopen's parser raises whatever it meets
            problems.append(f"canopen cannot load it: {reason(err)}")
    return problems


def _check_lists(eds: configparser.RawConfigParser, objects: dict[int, str]) -> list[str]:
    problems, listed = [], set()
    for name in LISTS:
        if not eds.has_section(name):
            problems.append(f"[{name}] is missing")
            continue
        entries = {k: v for k, v in eds.items(name) if k != "SupportedObjects"}
        count = _int(eds.get(name, "SupportedObjects", fallback="0"))
        if count != len(entries):
            problems.append(f"[{name}] SupportedObjects={count} but lists {len(entries)} objects")
        for value in entries.values():
            index = _int(value)
            listed.add(index)
            if index not in objects:
                problems.append(f"[{name}] lists 0x{index:04X}, which has no section")
    problems += [f"object 0x{i:04X} is in no object list" for i in sorted(set(objects) - listed)]
    return problems


def _check_object(eds: configparser.RawConfigParser, index: int, section: str,
                  subs: dict[int, str]) -> list[str]:
    object_type = _int(eds.get(section, "ObjectType", fallback="0x7"))
    if object_type in (0x8, 0x9):
        claimed = _int(eds.get(section, "SubNumber", fallback="0"))
        problems = []
        if claimed != len(subs):
            problems.append(f"[{section}] SubNumber={claimed} but has {len(subs)} sub-objects")
        for sub in sorted(subs.values()):
            problems += _check_var(eds, sub)
        return problems
    if object_type == 0x7:
        return _check_var(eds, section)
    return []


def _check_var(eds: configparser.RawConfigParser, section: str) -> list[str]:
    problems = []
    try:
        data_type = _int(eds.get(section, "DataType"))
    except (configparser.Error, ValueError):
        data_type = -1
    if data_type not in TYPE_BITS:
        problems.append(f"[{section}] DataType {eds.get(section, 'DataType', fallback='')!r} "
                        "is not a CiA 301 basic data type")
    access = eds.get(section, "AccessType", fallback="").lower()
    if access not in ACCESS_TYPES:
        problems.append(f"[{section}] AccessType {access!r} is not one of "
                        f"{', '.join(ACCESS_TYPES)}")
    return problems


def _check_mapping(eds: configparser.RawConfigParser, index: int,
                   subs: dict[int, str]) -> list[str]:
    if 0 not in subs:
        return [f"[{index:04X}] has no sub-index 0 (number of mapped objects)"]
    count = _int(eds.get(subs[0], "DefaultValue", fallback="0"))
    if not 0 <= count <= MAX_MAPPED:
        return [f"[{subs[0]}] maps {count} objects; a PDO maps 0..{MAX_MAPPED}"]
    problems, total = [], 0
    for s in range(1, count + 1):
        if s not in subs:
            problems.append(f"[{index:04X}] maps {count} objects but has no sub-index {s}")
            continue
        raw = _int(eds.get(subs[s], "DefaultValue", fallback="0"))
        target, sub, bits = raw >> 16, (raw >> 8) & 0xFF, raw & 0xFF
        total += bits
        name = f"0x{target:04X}:{sub:02X}"
        section = f"{target:04X}" if sub == 0 else f"{target:04X}sub{sub:X}"
        found = next((x for x in (section, section.upper(), section.lower())
                      if eds.has_section(x)), None)
        if found is None:
            problems.append(f"[{subs[s]}] maps {name}, which does not exist")
            continue
        if not _int(eds.get(found, "PDOMapping", fallback="0")):
            problems.append(f"[{subs[s]}] maps {name}, which is not PDO-mappable")
        size = TYPE_BITS.get(_int(eds.get(found, "DataType", fallback="0")))
        if size != bits:
            problems.append(f"[{subs[s]}] maps {bits} bits of {name}, which has {size}")
    if total > 64:
        problems.append(f"[{index:04X}] maps {total} bits, more than the 64 a PDO holds")
    return problems
