"""Frames as they go on the wire (ISO 11898-1:2015): the exact bits and how long they take.

Bit values: dominant = 0, recessive = 1. A frame as seen on an idle bus that acknowledges it:

Classic base format (11-bit id):  SOF, id 11, RTR, IDE 0, r0 0, DLC 4, data 8n, CRC 15
Classic extended (29-bit id):     SOF, id[28:18], SRR 1, IDE 1, id[17:0], RTR, r1 0, r0 0,
                                  DLC 4, data 8n, CRC 15
CAN FD base format:               SOF, id 11, RRS 0, IDE 0, FDF 1, res 0, BRS, ESI, DLC 4,
                                  data 8n, stuff count 4, CRC 17 or 21
CAN FD extended:                  SOF, id[28:18], SRR 1, IDE 1, id[17:0], RRS 0, FDF 1, res 0,
                                  BRS, ESI, DLC 4, data 8n, stuff count 4, CRC 17 or 21
then always: CRC delimiter 1, ACK slot 0 (a receiver acknowledged), ACK delimiter 1,
EOF 1111111, intermission 111 (the 3-bit interframe space before the next SOF).

Stuffing. Classic: from SOF to the last CRC bit, after 5 equal bits the transmitter inserts
one complementary bit, which counts as the first bit of the next run; a stuff bit follows
the last CRC bit too if it ends a run of 5. CRC-15 (x^15+x^14+x^10+x^8+x^7+x^4+x^3+1,
register starting at 0) is computed over the unstuffed bits SOF..data.

CAN FD: dynamic stuffing as above from SOF to the last data bit (the last DLC bit when there
is no data), except that no dynamic stuff bit follows that last bit: the fixed stuff bit
that opens the stuff count is the complement of the bit before it and does its job (the
stuff count does not count it either). The stuff count is the number of dynamic stuff bits
mod 8 as a 3-bit Gray code plus an even parity bit. Fixed stuff bits (each the complement of
the bit before it): one before the stuff count, then one after every 4th bit of stuff count
and CRC together: 6 with CRC-17 (data up to 16 bytes), 7 with CRC-21. The CRC (CRC-17 0x3685B
or CRC-21 0x302899, register starting at 1 followed by zeros) covers SOF..data *with* its
dynamic stuff bits, and the stuff count, not the fixed stuff bits.

Bit rate switch: with BRS recessive the data bitrate runs from ESI through the CRC
delimiter. The bitrate switches at the sample point of BRS and back at the sample point of
the CRC delimiter, so those two bits are each part nominal, part fast; together they last
exactly one nominal plus one data bit, which is how they are counted here: BRS as nominal,
the CRC delimiter as data phase. Every stuff bit inserted after BRS is in the data phase.

:func:`frame_bits` gives the counts fast: the header's stuffing state and CRC register
cached by header (id, format, DLC), the payload run through table-driven stuffing and CRC-15
16 bits at a time, the CRC's own stuffing in one look-up; nothing cached by payload, which
changes with every PDO. :func:`canbus.wireframe.wire_frame` builds the whole bit sequence one
bit at a time, plainly; it is the reference the fast path is tested against.
"""

from __future__ import annotations

import array
import functools
import struct
from typing import NamedTuple

FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
"""CAN FD payload length of each DLC code 0..15."""
IFS_BITS = 3
"""Intermission: the recessive bits between EOF and the next SOF."""
TAIL_BITS = 1 + 1 + 7 + IFS_BITS
"""ACK slot, ACK delimiter, EOF and intermission: nominal-rate bits after the CRC delimiter."""
CRC15, CRC17, CRC21 = 0x4599, 0x3685B, 0x302899

GRAY_PARITY = (0b0000, 0b0011, 0b0110, 0b0101, 0b1100, 0b1111, 0b1010, 0b1001)
"""Stuff count mod 8 -> 3-bit Gray code followed by its even parity bit."""
F_EXTENDED, F_REMOTE, F_FD, F_BRS, F_ESI = 1, 2, 4, 8, 16
"""Frame flags of :func:`bits_for`: 29-bit id, remote frame, CAN FD, bit rate switch, ESI."""
_MAX_STANDARD_ID, _MAX_EXTENDED_ID = 0x7FF, 0x1FFFFFFF


class FrameBits(NamedTuple):
    """Bits one frame occupies on the wire, intermission included."""

    nominal: int
    """Bits at the nominal bitrate (all of them unless CAN FD with bit rate switch)."""
    data: int
    """Bits at the data bitrate (ESI through the CRC delimiter of a CAN FD frame with BRS)."""
    stuff: int
    """Dynamic stuff bits (part of ``nominal`` and ``data``; fixed stuff bits are not counted)."""

    @property
    def total(self) -> int:
        return self.nominal + self.data

    def duration_s(self, bitrate: float, data_bitrate: float | None = None) -> float:
        """Seconds on the wire: nominal bits at ``bitrate``, the data phase at ``data_bitrate``."""
        if self.data == 0:
            return self.nominal / bitrate
        if data_bitrate is None:
            raise ValueError("a CAN FD frame with bit rate switch needs a data bitrate")
        return self.nominal / bitrate + self.data / data_bitrate


def fd_dlc(length: int) -> int:
    """The DLC code of the smallest CAN FD payload that holds ``length`` bytes."""
    for code, size in enumerate(FD_LENGTHS):
        if size >= length:
            return code
    raise ValueError(f"CAN FD carries at most 64 data bytes, got {length}")


def arbitration_key(can_id: int, *, extended: bool = False, remote: bool = False) -> int:
    """The arbitration field as a number: the smaller key wins arbitration.

    Bits in wire order: base id (11), then RTR (base format) or SRR = 1 (extended), IDE,
    then the 18 extension bits and RTR of an extended frame (zeros for a base frame, whose
    arbitration has ended). So a data frame beats a remote frame of the same id, and a base
    frame beats an extended frame with the same 11 leading id bits. CAN FD frames carry RRS
    = 0 where RTR would be: they arbitrate as data frames.
    """
    if extended:
        return (can_id >> 18) << 21 | 0b11 << 19 | (can_id & 0x3FFFF) << 1 | remote
    return can_id << 21 | remote << 20


def check(can_id: int, length: int, flags: int, dlc: int) -> None:
    """Raise ValueError naming what is wrong if the frame cannot exist (flags ``F_*``)."""
    limit = _MAX_EXTENDED_ID if flags & F_EXTENDED else _MAX_STANDARD_ID
    if not 0 <= can_id <= limit:
        raise ValueError(f"identifier 0x{can_id:X} out of range 0..0x{limit:X}")
    if flags & F_FD:
        if flags & F_REMOTE:
            raise ValueError("CAN FD has no remote frames")
        if length > 64:
            raise ValueError(f"CAN FD carries at most 64 data bytes, got {length}")
    else:
        if flags & (F_BRS | F_ESI):
            raise ValueError("BRS and ESI exist only in CAN FD frames")
        if not 0 <= dlc <= 8:
            raise ValueError(f"a classic CAN DLC is 0..8 here, got {dlc}")
        if length > 8 or (flags & F_REMOTE and length):
            raise ValueError(f"a classic {'remote' if flags & F_REMOTE else 'data'} frame "
                             f"cannot carry {length} data bytes")
        if not flags & F_REMOTE and length != dlc:
            raise ValueError(f"DLC {dlc} does not match {length} data bytes")


def flags_of(extended: bool, remote: bool, fd: bool, brs: bool, esi: bool) -> int:
    return (F_EXTENDED * extended | F_REMOTE * remote | F_FD * fd | F_BRS * (fd and brs)
            | F_ESI * (fd and esi))


# ----------------------------------------------------------------------------------------
# Fast path


def _crc15_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        reg = byte << 7
        for _ in range(8):
            reg = ((reg << 1) ^ CRC15 if reg & 0x4000 else reg << 1) & 0x7FFF
        table.append(reg)
    return tuple(table)


def _stuff_table(width: int) -> bytes:
    """Stuffing as a state machine over ``width``-bit chunks.

    State: the value of the current run and its length 1..4 (``value << 2 | length - 1``;
    a run of 5 has just taken a stuff bit, which starts a run of 1 of the other value).
    Entry ``[state << width | chunk]``: stuff bits inserted (0..4) | next state << 3 |
    64 if a stuff bit follows the chunk's last bit.
    """
    table = bytearray(8 << width)
    for state in range(8):
        for chunk in range(1 << width):
            value, run, count, last = state >> 2, (state & 3) + 1, 0, 0
            for shift in range(width - 1, -1, -1):
                bit = (chunk >> shift) & 1
                run, value, last = (run + 1 if bit == value else 1), bit, 0
                if run == 5:
                    value, run, count, last = 1 - bit, 1, count + 1, 64
            table[state << width | chunk] = count | (value << 2 | run - 1) << 3 | last
    return bytes(table)


_CRC15_TABLE = _crc15_table()
_STUFF8, _STUFF7 = _stuff_table(8), _stuff_table(7)


_WORDS = tuple(struct.Struct(f">{n}H").unpack_from for n in range(33))
_WORDS4 = struct.Struct(">4H").unpack


class _Tables(NamedTuple):
    stuff16: bytes
    """Stuffing over 16-bit words: ``[state << 16 | word]`` is ``next state << 5 | stuff
    bits``. The stuff bits sit in 5 bits so the entries of up to 7 words add up unmasked."""
    crc16: array.array[int]
    """CRC-15 over 16-bit words: the register after ``word`` is ``crc16[reg << 1 ^ word]``."""
    stuff_crc: bytes
    """Stuff bits in the 15 CRC bits, the one after the last included: ``[state << 15 | crc]``."""


@functools.cache
def _tables() -> _Tables:
    """The word tables, composed from the 8-bit ones (built on first use: about 10 ms)."""
    import numpy as np

    stuff8 = np.frombuffer(_STUFF8, dtype=np.uint8).reshape(8, 256).astype(np.int32)
    first = stuff8[:, :, None]
    second = stuff8[(first >> 3) & 7, np.arange(256)[None, None, :]]
    stuff16 = ((second >> 3) & 7) << 5 | ((first & 7) + (second & 7))
    crc8 = np.array(_CRC15_TABLE, dtype=np.int32)
    word = np.arange(1 << 16)
    high = crc8[word >> 8]
    crc16 = ((high << 8) & 0x7FFF) ^ crc8[(high >> 7) ^ (word & 0xFF)]
    crc = np.arange(1 << 15)
    head = stuff8[:, crc >> 7]
    tail = np.frombuffer(_STUFF7, dtype=np.uint8).reshape(8, 128)[(head >> 3) & 7, crc & 0x7F]
    stuff_crc = (head & 7) + (tail & 7)
    return _Tables(stuff16.astype(np.uint8).tobytes(),
                   array.array("H", crc16.astype(np.uint16).tobytes()),
                   stuff_crc.astype(np.uint8).tobytes())


def crc15(data: bytes) -> int:
    """CRC-15 of ``data`` read MSB first, register starting at 0 (leading zero bits are free)."""
    reg, table = 0, _CRC15_TABLE
    for byte in data:
        reg = ((reg << 8) & 0x7FFF) ^ table[(reg >> 7) ^ byte]
    return reg


def _header(value: int, length: int) -> tuple[int, int, int, int]:
    """Stuffing state, stuff bits, stuff-after-last flag and CRC-15 register after the
    ``length`` bits of ``value`` (a frame's first bits: SOF..DLC), one bit at a time."""
    run_value = run = count = last = reg = 0
    for shift in range(length - 1, -1, -1):
        bit = (value >> shift) & 1
        run, run_value, last = (run + 1 if bit == run_value and run else 1), bit, 0
        if run == 5:
            run_value, run, count, last = 1 - bit, 1, count + 1, 64
        feedback = bit ^ (reg >> 14)
        reg = (reg << 1) & 0x7FFF
        if feedback:
            reg ^= CRC15
    return run_value << 2 | run - 1, count, last, reg


def stuff_count(value: int, length: int, *, after_last: bool = True) -> int:
    """Dynamic stuff bits the ``length``-bit sequence ``value`` (MSB first, first bit 0) takes.

    With ``after_last`` False (CAN FD) no stuff bit follows the sequence's last bit.
    """
    _, count, last, _ = _header(value, length)
    return count - (not after_last and last > 0)


_HEADS: dict[int, tuple[int, int, int]] = {}
"""Classic frames: (id, IDE, RTR, DLC) -> stuffing state << 16, stuff bits, CRC register."""
_FD_HEADS: dict[int, tuple[int, int, int, int]] = {}
"""CAN FD frames: SOF..DLC -> stuffing state << 16, stuff bits, stuff-after-last flag,
stuff bits before BRS."""
_MAX_HEADS = 4096
_new_tuple = tuple.__new__  # FrameBits without its __new__'s Python call


def _classic_head(key: int, can_id: int, flags: int, dlc: int) -> tuple[int, int, int]:
    if flags & F_EXTENDED:
        value = ((can_id >> 18) << 27 | 0b11 << 25 | (can_id & 0x3FFFF) << 7
                 | (flags & F_REMOTE) << 5 | dlc)
        state, count, _, reg = _header(value, 39)
    else:
        state, count, _, reg = _header(can_id << 7 | (flags & F_REMOTE) << 5 | dlc, 19)
    if len(_HEADS) >= _MAX_HEADS:
        _HEADS.clear()
    head = _HEADS[key] = (state << 16, count, reg)
    return head


def _classic_stuff(can_id: int, flags: int, dlc: int, data: bytes | bytearray) -> int:
    """Dynamic stuff bits of a classic frame (SOF through the CRC).

    The header's state comes from a cache by (id, IDE, RTR, DLC); the payload goes through
    the stuffing and CRC-15 tables a 16-bit word at a time (unrolled for 8 bytes), then the
    CRC's own 15 bits in one look-up.
    """
    key = (can_id << 2 | flags & 3) << 4 | dlc
    head = _HEADS.get(key)
    if head is None:
        head = _classic_head(key, can_id, flags, dlc)
    state, count, crc = head
    stuff16, crc16, stuff_crc = _tables()
    if len(data) == 8:
        words: tuple[int, int, int, int] = _WORDS4(data)
        a, b, c, d = words
        e1 = stuff16[state | a]
        crc = crc16[crc << 1 ^ a]
        e2 = stuff16[(e1 & 0xE0) << 11 | b]
        crc = crc16[crc << 1 ^ b]
        e3 = stuff16[(e2 & 0xE0) << 11 | c]
        crc = crc16[crc << 1 ^ c]
        e4 = stuff16[(e3 & 0xE0) << 11 | d]
        crc = crc16[crc << 1 ^ d]
        return count + ((e1 + e2 + e3 + e4) & 31) + stuff_crc[(e4 & 0xE0) << 10 | crc]
    for word in _WORDS[len(data) >> 1](data):
        entry = stuff16[state | word]
        count += entry & 31
        state = (entry & 0xE0) << 11
        crc = crc16[crc << 1 ^ word]
    if len(data) & 1:
        byte = data[-1]
        entry = _STUFF8[state >> 8 | byte]
        count += entry & 7
        state = (entry & 0x38) << 13
        crc = ((crc << 8) & 0x7FFF) ^ _CRC15_TABLE[(crc >> 7) ^ byte]
    return count + stuff_crc[state >> 1 | crc]


def _fd_head(header: int, size: int, prefix: int) -> tuple[int, int, int, int]:
    state, count, last, _ = _header(header, size)
    head_stuff = _header(header >> (size - prefix), prefix)[1]  # stuffing is causal
    if len(_FD_HEADS) >= _MAX_HEADS:
        _FD_HEADS.clear()
    head = _FD_HEADS[header] = (state << 16, count, last, head_stuff)
    return head


def _fd_bits(can_id: int, flags: int, data: bytes | bytearray) -> FrameBits:
    code = fd_dlc(len(data))
    padded = FD_LENGTHS[code]
    if padded != len(data):
        data = bytes(data) + bytes(padded - len(data))
    brs, esi = (flags & F_BRS) >> 3, (flags & F_ESI) >> 4
    if flags & F_EXTENDED:
        header = (can_id >> 18) << 29 | 0b11 << 27 | (can_id & 0x3FFFF) << 9 | 0b010 << 6
        size, prefix = 41, 35  # prefix: SOF..res, the bits before BRS
    else:
        header, size, prefix = can_id << 10 | 0b0010 << 6, 22, 16
    header |= brs << 5 | esi << 4 | code
    head = _FD_HEADS.get(header)
    if head is None:
        head = _fd_head(header, size, prefix)
    state, stuff, last, head_stuff = head
    if padded:
        # every byte but the last a word at a time; the last one tells whether its run
        # ended on a stuff bit, which CAN FD leaves out there
        stuff16 = _tables().stuff16
        body = padded - 1
        for word in _WORDS[body >> 1](data):
            entry = stuff16[state | word]
            stuff += entry & 31
            state = (entry & 0xE0) << 11
        if body & 1:
            entry = _STUFF8[state >> 8 | data[body - 1]]
            stuff += entry & 7
            state = (entry & 0x38) << 13
        entry = _STUFF8[state >> 8 | data[body]]
        stuff += entry & 7
        last = entry & 64
    stuff -= last > 0  # no dynamic stuff bit after the last data bit: a fixed one follows
    crc_bits = 17 if padded <= 16 else 21
    fixed = 2 + crc_bits // 4  # before the stuff count, after it, after every 4th CRC bit
    fast = (size + 8 * padded - prefix - 1) + (stuff - head_stuff) + 4 + crc_bits + fixed + 1
    slow = prefix + 1 + head_stuff + TAIL_BITS
    if brs:
        return FrameBits(slow, fast, stuff)
    return FrameBits(slow + fast, 0, stuff)


def bits_unchecked(can_id: int, flags: int, dlc: int, data: bytes | bytearray) -> FrameBits:
    """:func:`bits_for` of a frame known to be valid (no checks): the wire's hot path.

    About 1.5 us for an 8-byte classic frame on the machine of docs/timedbus.md (where
    :func:`frame_bits`, checks included, takes 2.4), whatever its content: nothing is
    cached by payload, a cache's miss cost more than this.
    """
    if flags & F_FD:
        return _fd_bits(can_id, flags, data)
    stuff = _classic_stuff(can_id, flags, dlc, data)
    return _new_tuple(FrameBits, ((39 if flags & F_EXTENDED else 19) + 8 * len(data) + 28 + stuff,
                                  0, stuff))


def bits_for(can_id: int, flags: int, dlc: int, data: bytes | bytearray) -> FrameBits:
    """:func:`frame_bits` with the flags as one number (``F_*``); raises ValueError for a
    frame that cannot exist.

    ``dlc`` is the classic DLC; a CAN FD frame's comes from ``len(data)``.
    """
    check(can_id, len(data), flags, dlc)
    return bits_unchecked(can_id, flags, dlc, data)


def frame_bits(can_id: int, data: bytes, *, extended: bool = False, remote: bool = False,
               dlc: int | None = None, fd: bool = False, brs: bool = False,
               esi: bool = False) -> FrameBits:
    """Bits a frame occupies on the wire.

    ``data`` is the payload; a CAN FD payload whose length is not a DLC length is padded
    with zero bytes to the next one, as controllers send it. ``dlc`` is the classic DLC
    (default ``len(data)``; a remote frame gives the requested length and no data).
    """
    flags = flags_of(extended, remote, fd, brs, esi)
    return bits_for(can_id, flags, len(data) if dlc is None or fd else dlc, bytes(data))


# ----------------------------------------------------------------------------------------
