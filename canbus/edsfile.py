"""EDS files read without trust: one line per problem, before canopen builds anything.

canopen's ``import_od`` reads an EDS with ``configparser`` and converts its values with
``int(text, 0)`` as it goes: a non-numeric ``SubNumber``, ``ObjectType``, ``DataType``
or ``DummyUsage`` entry is a traceback, a default it cannot convert is silently dropped,
and a parse error is a multi-line message without the file's name. :func:`read_eds`
reads the file (at most :data:`MAX_BYTES`, strict UTF-8, duplicate sections and keys
refused as canopen refuses them) and :func:`value_problems` checks every value canopen
will convert, by its data type: integers in the type's range (with a ``$NODEID``
expression of the form ``$NODEID+N`` or ``N+$NODEID`` for node-ID 1..127), finite
floats, hex octet strings, ``LowLimit`` <= ``DefaultValue`` <= ``HighLimit``, counts
(``SubNumber``, ``CompactSubObj``, ``NrOfEntries``, ``SupportedObjects``, ``Lines``)
within what CANopen allows before anything loops over them. :func:`check_loadable`
turns the first problem into a ConfigError naming the file, the section and the key.
"""

from __future__ import annotations

import configparser
import math
import os
import re
from collections.abc import Iterator
from pathlib import Path

from skin.errors import ConfigError

MAX_BYTES = 4 << 20
OBJECT = re.compile(r"^([0-9A-Fa-f]{4})$")
SUB = re.compile(r"^([0-9A-Fa-f]{4})[Ss]ub([0-9A-Fa-f]+)$")
NAMES = re.compile(r"^([0-9A-Fa-f]{4})Name")
DUMMY = re.compile(r"^[Dd]ummy[Uu]sage$")
LISTS = ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects")
ACCESS_TYPES = ("ro", "wo", "rw", "rwr", "rww", "const")
OBJECT_TYPES = (0x0, 0x2, 0x5, 0x6, 0x7, 0x8, 0x9)
# CiA 301 basic types: (bits, signed) of the integers; REAL32/64; strings and domains.
INTEGERS = {0x01: (1, False), 0x02: (8, True), 0x03: (16, True), 0x04: (32, True),
            0x05: (8, False), 0x06: (16, False), 0x07: (32, False), 0x10: (24, True),
            0x11: (64, False), 0x12: (40, True), 0x13: (48, True), 0x14: (56, True),
            0x15: (64, True), 0x16: (24, False), 0x18: (40, False), 0x19: (48, False),
            0x1A: (56, False), 0x1B: (64, False), 0x0C: (48, False), 0x0D: (48, False)}
FLOATS = (0x08, 0x11)
OCTETS = (0x0A, 0x0F)  # OCTET_STRING, DOMAIN: hex digits
TEXTS = (0x09, 0x0B)  # VISIBLE_STRING, UNICODE_STRING
_NODEID = re.compile(r"^\$NODEID\+(.+)$|^(.+)\+\$NODEID$|^\$NODEID$", re.IGNORECASE)
_VALUE_KEYS = ("LowLimit", "HighLimit", "DefaultValue", "ParameterValue")


def _new_parser() -> configparser.RawConfigParser:
    eds = configparser.RawConfigParser(inline_comment_prefixes=(";",), strict=True)
    eds.optionxform = str  # type: ignore[assignment,method-assign]
    return eds


def _parse_error(err: configparser.Error) -> str:
    """configparser's message (several lines for a ParsingError) as one line."""
    if isinstance(err, configparser.MissingSectionHeaderError):
        return f"line {err.lineno}: text before the first [section]"
    if isinstance(err, configparser.ParsingError) and err.errors:
        line, text = err.errors[0]
        more = f" (and {len(err.errors) - 1} more)" if len(err.errors) > 1 else ""
        return f"line {line}: not a key=value line or a [section]: {text.strip()[:60]!r}{more}"
    if isinstance(err, configparser.DuplicateSectionError | configparser.DuplicateOptionError):
        where = f"line {err.lineno}: " if err.lineno else ""
        what = f"[{err.section}] {err.option}" if isinstance(
            err, configparser.DuplicateOptionError) else f"[{err.section}]"
        return f"{where}{what} is given twice"
    return " ".join(str(err).split())


def read_eds(path: str | os.PathLike[str]) -> configparser.RawConfigParser:
    """The sections of the EDS at ``path``; ConfigError naming the file and the line."""
    source = os.fspath(path)
    try:
        with Path(path).open("rb") as handle:
            raw = handle.read(MAX_BYTES + 1)
    except OSError as err:
        raise ConfigError("eds", f"cannot read {source!r}: {err.strerror}") from err
    if len(raw) > MAX_BYTES:
        raise ConfigError("", f"larger than the {MAX_BYTES >> 20} MiB an EDS may have",
                          source=source)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        line = raw.count(b"\n", 0, err.start) + 1
        raise ConfigError("", f"not UTF-8 text: byte 0x{raw[err.start]:02X} at line {line}",
                          source=source) from None
    eds = _new_parser()
    try:
        eds.read_string(text, source)
    except configparser.Error as err:
        raise ConfigError("", _parse_error(err), source=source) from None
    return eds


def integer(text: str) -> int | None:
    """``int(text, 0)`` as canopen reads it, or None."""
    try:
        return int(text, 0)
    except ValueError:
        return None


def _node_value(text: str) -> int | None:
    """A value with an optional ``$NODEID`` term, at node-ID 0 (None if unreadable)."""
    compact = text.replace(" ", "")  # as canopen reads values that may name $NODEID
    match = _NODEID.match(compact)
    if match is None:
        return integer(compact)
    rest = match.group(1) or match.group(2)
    return 0 if rest is None else integer(rest)


def _range(data_type: int) -> tuple[int, int]:
    bits, signed = INTEGERS[data_type]
    if data_type == 0x01:
        return 0, 1
    return (-(1 << (bits - 1)), (1 << bits) - 1) if signed else (0, (1 << bits) - 1)


def _value(text: str, data_type: int, key: str) -> tuple[float | None, str | None]:
    """(the value as a number where it is one, the problem or None)."""
    if data_type in INTEGERS:
        value = _node_value(text)
        if value is None:
            return None, f"{key} {text!r} is not an integer (or $NODEID+N)"
        low, high = _range(data_type)
        relative = "$NODEID" in text.upper()
        if not low <= value <= high - (127 if relative else 0):
            shown = text if len(text) <= 24 else text[:24] + "..."
            return None, f"{key} {shown} is out of range {low}..{high} of data type " \
                         f"0x{data_type:04X}" + (" at node-ID 127" if relative else "")
        return value, None
    if data_type in FLOATS:
        try:
            number = float(text)
        except ValueError:
            return None, f"{key} {text!r} is not a number"
        return (number, None) if math.isfinite(number) or key != "DefaultValue" else \
            (None, f"{key} {text!r} is not finite")
    if data_type in OCTETS:
        try:
            bytes.fromhex(text)
        except ValueError:
            return None, f"{key} {text[:24]!r} is not hex octets"
    return None, None


def _variable(eds: configparser.RawConfigParser, section: str) -> Iterator[str]:
    head = f"[{section}]"
    data_type = integer(eds.get(section, "DataType", fallback=""))
    if data_type is None:
        yield f"{head} DataType {eds.get(section, 'DataType', fallback='(missing)')!r} is " \
              "not an integer"
        return
    if not eds.has_option(section, "AccessType"):
        yield f"{head} AccessType is missing"
    if data_type > 0x1B:
        return  # a defined type: reference_problems
    mapping = eds.get(section, "PDOMapping", fallback="0")
    if integer(mapping) not in (0, 1):
        yield f"{head} PDOMapping {mapping!r} is not 0 or 1"
    values: dict[str, float] = {}
    for key in _VALUE_KEYS:
        if eds.has_option(section, key):
            value, problem = _value(eds.get(section, key), data_type, key)
            if problem is not None:
                yield f"{head} {problem}"
            elif value is not None:
                values[key] = value
    low, high = values.get("LowLimit"), values.get("HighLimit")
    if low is not None and high is not None and low > high:
        yield f"{head} LowLimit {eds.get(section, 'LowLimit')} is above HighLimit " \
              f"{eds.get(section, 'HighLimit')}"
        return
    default = values.get("DefaultValue")
    if default is not None and "$NODEID" not in eds.get(section, "DefaultValue").upper() and \
            ((low is not None and default < low) or (high is not None and default > high)):
        yield f"{head} DefaultValue {eds.get(section, 'DefaultValue')} is outside " \
              f"LowLimit..HighLimit"


def _count(eds: configparser.RawConfigParser, section: str, key: str, high: int,
           required: bool = False) -> Iterator[str]:
    if not eds.has_option(section, key):
        if required:
            yield f"[{section}] {key} is missing"
        return
    value = integer(eds.get(section, key))
    if value is None or not 0 <= value <= high:
        yield f"[{section}] {key} {eds.get(section, key)[:24]!r} is not a count in 0..{high}"


def _object(eds: configparser.RawConfigParser, section: str) -> Iterator[str]:
    if not eds.has_option(section, "ParameterName"):
        yield f"[{section}] ParameterName is missing"
    object_type = integer(eds.get(section, "ObjectType", fallback="0x7"))
    if object_type not in OBJECT_TYPES:
        yield f"[{section}] ObjectType {eds.get(section, 'ObjectType')[:24]!r} is not a " \
              "CANopen object type (0x7 VAR, 0x8 ARRAY, 0x9 RECORD, ...)"
        return
    yield from _count(eds, section, "SubNumber", 0xFF)
    yield from _count(eds, section, "CompactSubObj", 0xFE)
    if object_type in (0x2, 0x7) or (object_type == 0x8 and
                                     eds.has_option(section, "CompactSubObj")):
        yield from _variable(eds, section)


def _names(eds: configparser.RawConfigParser, section: str, index: str) -> Iterator[str]:
    """A [xxxxName] section names the entries of a CompactSubObj array (read in decimal)."""
    owner = next((s for s in (index, index.upper(), index.lower()) if eds.has_section(s)), None)
    if owner is None or not eds.has_option(owner, "CompactSubObj"):
        yield f"[{section}] names the entries of {index}, which is no CompactSubObj array"
    value = eds.get(section, "NrOfEntries", fallback="(missing)").strip()
    if not (value.isdigit() and int(value) <= 0xFE):
        yield f"[{section}] NrOfEntries {value[:24]!r} is not a count in 0..254"


def value_problems(eds: configparser.RawConfigParser) -> list[str]:
    """Every value canopen would fail on or silently drop, one line each."""
    problems: list[str] = []
    objects = {int(m.group(1), 16) for s in eds.sections() if (m := OBJECT.match(s))}
    for section in eds.sections():
        if OBJECT.match(section):
            problems += _object(eds, section)
        elif (m := SUB.match(section)) and int(m.group(1), 16) in objects:
            if int(m.group(2), 16) > 0xFF:
                problems.append(f"[{section}] sub-index above 0xFF")
            else:
                if not eds.has_option(section, "ParameterName"):
                    problems.append(f"[{section}] ParameterName is missing")
                problems += _variable(eds, section)
        elif DUMMY.match(section):
            for key in (f"Dummy{i:04d}" for i in range(1, 8)):
                value = eds.get(section, key, fallback="(missing)")
                if value.strip() not in ("0", "1"):
                    problems.append(f"[{section}] {key} {value[:24]!r} is not 0 or 1")
    problems += _info_problems(eds)
    return problems


def reference_problems(eds: configparser.RawConfigParser) -> list[str]:
    """Sections that name what is not there (canopen fails on them): sub-objects of a
    missing object, data types above 0x1B without their definition, names of an array
    that is not a CompactSubObj array."""
    problems: list[str] = []
    objects = {int(m.group(1), 16) for s in eds.sections() if (m := OBJECT.match(s))}
    for section in eds.sections():
        if (m := SUB.match(section)) and int(m.group(1), 16) not in objects:
            problems.append(f"[{section}] belongs to object {m.group(1)}, which has no section")
        elif m := NAMES.match(section):
            problems += _names(eds, section, m.group(1))
        elif OBJECT.match(section) or SUB.match(section):
            data_type = integer(eds.get(section, "DataType", fallback="0")) or 0
            definition = f"{data_type:X}sub1"
            if data_type > 0x1B and \
                    integer(eds.get(definition, "DefaultValue", fallback="")) is None:
                problems.append(f"[{section}] DataType 0x{data_type:04X} is neither a basic "
                                f"type nor defined in [{definition}]")
    return problems


def _info_problems(eds: configparser.RawConfigParser) -> Iterator[str]:
    for name in LISTS:
        if eds.has_section(name):
            yield from _count(eds, name, "SupportedObjects", 0xFFFF)
            for key, value in eds.items(name):
                if key != "SupportedObjects" and (integer(value) is None or
                                                  not 0 <= (integer(value) or 0) <= 0xFFFF):
                    yield f"[{name}] {key}={value[:24]} is not an object index"
    if not eds.has_section("DeviceInfo"):
        yield "[DeviceInfo] is missing (CiA 306 requires it)"
    else:
        for key, value in eds.items("DeviceInfo"):
            if (key.startswith(("BaudRate_", "NrOf", "Simple", "LSS_")) or key in
                    ("VendorNumber", "ProductNumber", "RevisionNumber", "Granularity",
                     "DynamicChannelsSupported", "GroupMessaging")) and integer(value) is None:
                yield f"[DeviceInfo] {key} {value[:24]!r} is not an integer"
    if eds.has_section("Comments"):
        lines = integer(eds.get("Comments", "Lines", fallback="0"))
        if lines is None or not 0 <= lines <= 0xFFFF:
            yield f"[Comments] Lines {eds.get('Comments', 'Lines')[:24]!r} is not a count"
        else:
            missing = next((k for k in range(1, lines + 1)
                            if not eds.has_option("Comments", f"Line{k}")), None)
            if missing is not None:
                yield f"[Comments] Lines={lines} but Line{missing} is missing"
    if eds.has_section("DeviceComissioning"):
        baud = eds.get("DeviceComissioning", "Baudrate", fallback="0").strip()
        if not baud.lstrip("+-").isdigit():
            yield f"[DeviceComissioning] Baudrate {baud[:24]!r} is not a whole number"
        node = eds.get("DeviceComissioning", "NodeID", fallback="0")
        if integer(node) is None:
            yield f"[DeviceComissioning] NodeID {node[:24]!r} is not an integer"


def check_loadable(path: str | os.PathLike[str]) -> configparser.RawConfigParser:
    """:func:`read_eds` and :func:`value_problems`; the first problem as a ConfigError."""
    eds = read_eds(path)
    problems = value_problems(eds) or reference_problems(eds)
    if problems:
        more = f" (and {len(problems) - 1} more: skin eds check)" if len(problems) > 1 else ""
        raise ConfigError("", problems[0] + more, source=os.fspath(path))
    return eds
