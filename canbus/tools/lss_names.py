"""LSS frames (CiA 305) in words: ``0x7E5`` requests of the master, ``0x7E4`` answers.

``switch state selective serial 0x00001001``, ``configure node-ID 5``,
``configure node-ID: ok``, ``fastscan id 0x00000000 bit 31 sub 3 next 3``,
``identify: a slave matches``, ``inquire node-ID: 5``, ``store configuration: storage
error``. A frame of another length, or an unknown command specifier, is shown in hex.
"""

from __future__ import annotations

import struct

LSS_MASTER = 0x7E5

_PARTS = ("vendor", "product", "revision", "serial")
_REQUESTS = {
    0x11: "configure node-ID", 0x13: "configure bit timing", 0x15: "activate bit timing",
    0x17: "store configuration", 0x4C: "identify non-configured remote slave",
    0x5A: "inquire vendor", 0x5B: "inquire product", 0x5C: "inquire revision",
    0x5D: "inquire serial", 0x5E: "inquire node-ID",
}
_IDENTIFY = ("vendor", "product", "revision low", "revision high", "serial low", "serial high")
_ERRORS = {0x11: {0: "ok", 1: "node-ID out of range"},
           0x13: {0: "ok", 1: "bit timing not supported"},
           0x17: {0: "ok", 1: "not supported", 2: "storage error"}}
_BIT_TIMINGS = {0: "1000", 1: "800", 2: "500", 3: "250", 4: "125", 6: "50", 7: "20",
                8: "10", 9: "automatic"}


def describe_lss(cob_id: int, data: bytes) -> str:
    """One LSS frame in words."""
    if len(data) != 8:
        return f"{data.hex(' ')} (length {len(data)}: not an LSS frame)"
    cs, value = data[0], struct.unpack_from("<I", data, 1)[0]
    text = _request(cs, data, value) if cob_id == LSS_MASTER else _answer(cs, data, value)
    return text if text is not None else f"{data.hex(' ')} (unknown LSS command 0x{cs:02X})"


def _request(cs: int, data: bytes, value: int) -> str | None:
    if cs == 0x04:
        return {0: "switch state global: waiting", 1: "switch state global: configuration"
                }.get(data[1], f"switch state global: mode {data[1]}?")
    if 0x40 <= cs <= 0x43:
        return f"switch state selective {_PARTS[cs - 0x40]} 0x{value:08X}"
    if 0x46 <= cs <= 0x4B:
        return f"identify remote slave {_IDENTIFY[cs - 0x46]} 0x{value:08X}"
    if cs == 0x51:
        check = "confirm" if data[5] == 0x80 else f"bit {data[5]}"
        return f"fastscan id 0x{value:08X} {check} sub {data[6]} next {data[7]}"
    if cs == 0x11:
        return f"configure node-ID {'0xFF (unconfigured)' if data[1] == 0xFF else data[1]}"
    if cs == 0x13:
        rate = _BIT_TIMINGS.get(data[2], "?") if data[1] == 0 else "?"
        return f"configure bit timing table {data[1]} index {data[2]} ({rate} kbit/s)"
    if cs == 0x15:
        return f"activate bit timing after {struct.unpack_from('<H', data, 1)[0]} ms"
    return _REQUESTS.get(cs)


def _answer(cs: int, data: bytes, value: int) -> str | None:
    if cs in _ERRORS:
        error = _ERRORS[cs].get(data[1], f"error {data[1]}")
        return f"{_REQUESTS[cs]}: {error}"
    if cs == 0x44:
        return "switch state selective: the slave is in configuration state"
    if cs == 0x4F:
        return "identify: a slave matches"
    if cs == 0x50:
        return "identify: a non-configured slave is present"
    if cs == 0x5E:
        return f"inquire node-ID: {'0xFF (unconfigured)' if data[1] == 0xFF else data[1]}"
    if 0x5A <= cs <= 0x5D:
        return f"{_REQUESTS[cs]}: 0x{value:08X}"
    return None
