"""What lely's ``dcfchk`` (dcf-tools) checks in an EDS, and what reads differently by reader.

An arm's master built on lely-core is configured by ``dcfgen`` from the slaves' EDS files,
which refuses a file ``dcfchk`` warns about. The rules, after dcf-tools' ``dcf/lint.py``
and ``dcf/device.py`` (CiA 306):

1. [FileInfo], [DeviceInfo] and [DeviceComissioning] hold only the keys CiA 306 defines;
   [DummyUsage] only ``DummyXXXX`` entries with a value of 0 or 1; no other section than
   those, [Comments], the object lists and object sections (``XXXX``, ``XXXXsubY``,
   ``XXXXName``, ``XXXXValue``);
2. [MandatoryObjects] lists only 0x1000, 0x1001, 0x1018; [OptionalObjects] no object of
   0x2000..0x5FFF, [ManufacturerObjects] only those; no data-type object (< 0x1000);
3. an object section holds only CiA 306 keys and a ParameterName; a VAR has a DataType; an
   ARRAY or RECORD has no AccessType and its sub-index 0 is UNSIGNED8; SubNumber only on an
   ARRAY or RECORD; a sub-object has an AccessType;
4. DefaultValue, ParameterValue, LowLimit and HighLimit of an integer type are integers
   (decimal or 0x, optionally ``$NODEID+``) inside the type's range and the object's limits;
5. a REAL32/REAL64 value other than 0 is flagged: lely reads it as the float's bit
   pattern (``0x3D4CCCCD``), python-canopen as a decimal (``0.05``), so no spelling means
   the same number to both;
6. [DeviceInfo] VendorNumber, ProductNumber, RevisionNumber agree with 0x1018's defaults.
"""

from __future__ import annotations

import configparser
import re

FILE_INFO = {"filename", "fileversion", "filerevision", "edsversion", "description",
             "creationtime", "creationdate", "createdby", "modificationtime",
             "modificationdate", "modifiedby", "lasteds"}
DEVICE_COMMISSIONING = {"nodeid", "nodename", "noderefd", "baudrate", "netnumber",
                        "networkname", "netrefd", "canopenmanager", "lss_serialnumber"}
DEVICE_INFO = {"vendorname", "vendornumber", "productname", "productnumber", "revisionnumber",
               "ordercode", "baudrate_10", "baudrate_20", "baudrate_50", "baudrate_125",
               "baudrate_250", "baudrate_500", "baudrate_800", "baudrate_1000",
               "simplebootupmaster", "simplebootupslave", "granularity",
               "dynamicchannelssupported", "groupmessaging", "nrofrxpdo", "nroftxpdo",
               "lss_supported", "compactpdo"}
KEYED_SECTIONS = {"fileinfo": FILE_INFO, "devicecomissioning": DEVICE_COMMISSIONING,
                  "deviceinfo": DEVICE_INFO}
OBJECT_KEYS = {"subnumber", "parametername", "objecttype", "datatype", "accesstype",
               "lowlimit", "highlimit", "defaultvalue", "pdomapping", "objflags",
               "compactsubobj", "parametervalue", "uploadfile", "downloadfile", "denotation",
               "paramrefd"}
LIMITS = {0x01: (0, 1), 0x02: (-0x80, 0x7F), 0x03: (-0x8000, 0x7FFF),
          0x04: (-0x8000_0000, 0x7FFF_FFFF), 0x05: (0, 0xFF), 0x06: (0, 0xFFFF),
          0x07: (0, 0xFFFF_FFFF), 0x10: (-0x80_0000, 0x7F_FFFF), 0x12: (-(1 << 39), (1 << 39) - 1),
          0x13: (-(1 << 47), (1 << 47) - 1), 0x14: (-(1 << 55), (1 << 55) - 1),
          0x15: (-(1 << 63), (1 << 63) - 1), 0x16: (0, 0xFF_FFFF), 0x18: (0, (1 << 40) - 1),
          0x19: (0, (1 << 48) - 1), 0x1A: (0, (1 << 56) - 1), 0x1B: (0, (1 << 64) - 1)}
REALS = (0x08, 0x11)
VALUE_KEYS = ("DefaultValue", "ParameterValue")
_SECTION = re.compile(r"^([0-9A-F]{4})(Name|Value|sub([0-9A-F]+))?$", re.IGNORECASE)
_VALUE = re.compile(r"^(\$NODEID\s*\+\s*)?(-?0x[0-9A-F]+|-?[0-9]+)$", re.IGNORECASE)
_LISTS = ("mandatoryobjects", "optionalobjects", "manufacturerobjects")


def lint(eds: configparser.RawConfigParser) -> list[str]:
    """One line per rule of the module's docstring that the file breaks."""
    problems: list[str] = []
    for section in eds.sections():
        low = section.lower()
        if low in KEYED_SECTIONS:
            problems += [f"[{section}] {key}: not a CiA 306 entry of this section"
                         for key in eds.options(section) if key.lower() not in KEYED_SECTIONS[low]]
        elif low == "dummyusage":
            problems += _dummy_usage(eds, section)
        elif low in _LISTS:
            problems += _object_list(eds, section, low)
        elif low == "comments":
            continue
        elif m := _SECTION.match(section):
            index = int(m.group(1), 16)
            if m.group(2) is None:
                problems += _object(eds, section)
            elif m.group(3) is not None:
                problems += _sub_object(eds, section, index)
        else:
            problems.append(f"[{section}]: not a section an EDS has (CiA 306)")
    return problems + _identity(eds)


def _dummy_usage(eds: configparser.RawConfigParser, section: str) -> list[str]:
    problems = []
    for key, value in eds.items(section):
        if not re.match(r"^Dummy[0-9A-F]{4}$", key, re.IGNORECASE):
            problems.append(f"[{section}] {key}: not a DummyXXXX entry")
        elif value.strip() not in ("0", "1"):
            problems.append(f"[{section}] {key}={value}: must be 0 or 1")
    return problems


def _object_list(eds: configparser.RawConfigParser, section: str, kind: str) -> list[str]:
    problems = []
    for key, value in eds.items(section):
        if key.lower() == "supportedobjects":
            continue
        try:
            index = int(value, 0)
        except ValueError:
            problems.append(f"[{section}] {key}={value}: not an object index")
            continue
        where = f"[{section}] {key}=0x{index:04X}"
        if index < 0x1000:
            problems.append(f"{where}: data type objects are not supported")
        elif kind == "mandatoryobjects" and index not in (0x1000, 0x1001, 0x1018):
            problems.append(f"{where}: not a CiA 301 mandatory object")
        elif kind == "optionalobjects" and 0x2000 <= index < 0x6000:
            problems.append(f"{where}: manufacturer-specific, belongs in [ManufacturerObjects]")
        elif kind == "manufacturerobjects" and not 0x2000 <= index < 0x6000:
            problems.append(f"{where}: not manufacturer-specific (0x2000..0x5FFF)")
    return problems


def _keys(eds: configparser.RawConfigParser, section: str) -> list[str]:
    out = [f"[{section}] {key}: not a CiA 306 object entry"
           for key in eds.options(section) if key.lower() not in OBJECT_KEYS]
    if not eds.has_option(section, "ParameterName"):
        out.append(f"[{section}]: no ParameterName")
    return out


def _object(eds: configparser.RawConfigParser, section: str) -> list[str]:
    problems = _keys(eds, section)
    object_type = _number(eds.get(section, "ObjectType", fallback="0x7")) or 0x7
    sub_number = _number(eds.get(section, "SubNumber", fallback="0")) or 0
    composite = object_type in (0x8, 0x9)
    if object_type in (0x5, 0x7) and not eds.get(section, "DataType", fallback=""):
        problems.append(f"[{section}]: a VAR needs a DataType")
    own_access = bool(eds.get(section, "AccessType", fallback=""))
    if composite and own_access and not eds.has_option(section, "CompactSubObj"):
        problems.append(f"[{section}]: an ARRAY or RECORD has no AccessType of its own")
    if sub_number and not composite:
        problems.append(f"[{section}]: SubNumber on an object that is not an ARRAY or RECORD")
    if sub_number:
        sub0 = f"{section}sub0"
        found = next((s for s in eds.sections() if s.lower() == sub0.lower()), None)
        if found is not None and _number(eds.get(found, "DataType", fallback="")) != 0x05:
            problems.append(f"[{found}]: sub-index 0 must be UNSIGNED8")
    else:
        problems += _values(eds, section)
    return problems


def _sub_object(eds: configparser.RawConfigParser, section: str, index: int) -> list[str]:
    problems = _keys(eds, section)
    if not any(s.lower() == f"{index:04x}" for s in eds.sections()):
        problems.append(f"[{section}]: object 0x{index:04X} is not defined")
    if not eds.get(section, "AccessType", fallback=""):
        problems.append(f"[{section}]: no AccessType")
    return problems + _values(eds, section)


def _values(eds: configparser.RawConfigParser, section: str) -> list[str]:
    data_type = _number(eds.get(section, "DataType", fallback=""))
    if data_type is None:
        return []
    if data_type in REALS:
        return [f"[{section}] {key}={text}: a REAL value other than 0 reads differently by "
                "reader (lely: the float's bit pattern; python-canopen: a decimal)"
                for key in (*VALUE_KEYS, "LowLimit", "HighLimit")
                if (text := eds.get(section, key, fallback="").strip()) and _number(text) != 0]
    if data_type not in LIMITS:
        return [f"[{section}] {key}: the data type has no limits"
                for key in ("LowLimit", "HighLimit") if eds.get(section, key, fallback="")]
    low, high = LIMITS[data_type]
    problems, bounds = [], {}
    for key in ("LowLimit", "HighLimit"):
        text = eds.get(section, key, fallback="").strip()
        if text:
            span = _span(text)
            if span is None or not low <= span[0] <= span[1] <= high:
                problems.append(f"[{section}] {key}={text}: not an integer of the data type")
            else:
                bounds[key] = span[0] if key == "LowLimit" else span[1]
    low, high = bounds.get("LowLimit", low), bounds.get("HighLimit", high)
    for key in VALUE_KEYS:
        text = eds.get(section, key, fallback="").strip()
        if not text:
            continue
        span = _span(text)
        if span is None:
            problems.append(f"[{section}] {key}={text}: not an integer (decimal, 0x, $NODEID+)")
        elif not low <= span[0] <= span[1] <= high:
            problems.append(f"[{section}] {key}={text}: outside {low}..{high} for some node-ID")
    return problems


def _identity(eds: configparser.RawConfigParser) -> list[str]:
    problems = []
    for key, sub in (("VendorNumber", 1), ("ProductNumber", 2), ("RevisionNumber", 3)):
        info = eds.get("DeviceInfo", key, fallback="") if eds.has_section("DeviceInfo") else ""
        section = next((s for s in eds.sections() if s.lower() == f"1018sub{sub}"), None)
        if not info or section is None:
            continue
        listed = _number(info)
        default = _number(eds.get(section, "DefaultValue", fallback="0"))
        if listed is not None and default not in (None, 0, listed):
            problems.append(f"[DeviceInfo] {key}={info} differs from 0x1018 sub {sub} "
                            f"({default:#x})")
    return problems


def _span(text: str) -> tuple[int, int] | None:
    """The values ``text`` can take: itself, or with ``$NODEID+`` over node-IDs 1..127."""
    m = _VALUE.match(text.strip())
    if m is None:
        return None
    digits = m.group(2)
    value = int(digits, 16 if "x" in digits.lower() else 10)
    return (value + 1, value + 127) if m.group(1) else (value, value)


def _number(text: str) -> int | None:
    try:
        return int(text.strip(), 0)
    except ValueError:
        return None
