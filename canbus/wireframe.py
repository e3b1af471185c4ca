"""A frame built one bit at a time, plainly, from SOF through the intermission: the reference
that :func:`canbus.framebits.frame_bits`'s fast counts are tested against, and a frame's bits
to read back (the layout and the stuffing rules: :mod:`canbus.framebits`)."""

from __future__ import annotations

from dataclasses import dataclass

from canbus.framebits import (
    CRC15,
    CRC17,
    CRC21,
    FD_LENGTHS,
    GRAY_PARITY,
    IFS_BITS,
    FrameBits,
    check,
    fd_dlc,
    flags_of,
)


@dataclass(frozen=True)
class WireFrame:
    """Every bit of one frame from SOF through the intermission, as the wire carries it."""

    bits: str
    """'0' dominant, '1' recessive; the ACK slot as acknowledged (dominant)."""
    stuffed_end: int
    """Bits ``[0, stuffed_end)`` are under dynamic stuffing (SOF..CRC; FD: SOF..data)."""
    stuff_at: tuple[int, ...]
    """Indices of the dynamic stuff bits."""
    fixed_stuff_at: tuple[int, ...]
    """Indices of the fixed stuff bits (CAN FD)."""
    data_phase: tuple[int, int]
    """``[start, end)`` of the bits at the data bitrate; empty unless CAN FD with BRS."""
    crc: int
    stuff_count: int
    """The stuff count field's value before Gray coding (CAN FD), else 0."""

    @property
    def counts(self) -> FrameBits:
        start, end = self.data_phase
        return FrameBits(len(self.bits) - (end - start), end - start, len(self.stuff_at))


def _bits_of(value: int, width: int) -> list[int]:
    return [(value >> shift) & 1 for shift in range(width - 1, -1, -1)]


def _crc(bits: list[int], poly: int, width: int, init: int) -> int:
    reg, top, mask = init, 1 << (width - 1), (1 << width) - 1
    for bit in bits:
        feedback = bit ^ bool(reg & top)
        reg = (reg << 1) & mask
        if feedback:
            reg ^= poly & mask
    return reg


def _stuff(bits: list[int], *, after_last: bool) -> tuple[list[int], list[int], list[int]]:
    """Insert dynamic stuff bits: the stuffed bits, the stuff bits' indices and, for every
    input bit, its index in the stuffed sequence."""
    out: list[int] = []
    at: list[int] = []
    where: list[int] = []
    run_value, run = -1, 0
    for i, bit in enumerate(bits):
        where.append(len(out))
        out.append(bit)
        run = run + 1 if bit == run_value else 1
        run_value = bit
        if run == 5 and (after_last or i < len(bits) - 1):
            at.append(len(out))
            out.append(1 - bit)
            run_value, run = 1 - bit, 1
    return out, at, where


def wire_frame(can_id: int, data: bytes, *, extended: bool = False, remote: bool = False,
               dlc: int | None = None, fd: bool = False, brs: bool = False,
               esi: bool = False) -> WireFrame:
    """The frame's bits on the wire, built field by field (the reference for :func:`frame_bits`)."""
    flags = flags_of(extended, remote, fd, brs, esi)
    data = bytes(data)
    if fd:
        dlc = fd_dlc(len(data))
        data = data + bytes(FD_LENGTHS[dlc] - len(data))
    elif dlc is None:
        dlc = len(data)
    check(can_id, len(data), flags, dlc)
    bits = [0]  # SOF
    if extended:
        bits += [*_bits_of(can_id >> 18, 11), 1, 1, *_bits_of(can_id & 0x3FFFF, 18)]
    else:
        bits += _bits_of(can_id, 11)
    if fd:
        bits += [0] if extended else [0, 0]  # RRS (and IDE of a base frame)
        bits += [1, 0]  # FDF, res
        brs_at = len(bits)
        bits += [int(brs), int(esi)]
    else:
        bits += [int(remote), 0, 0]  # RTR, then IDE and r0 (base) or r1 and r0 (extended)
    bits += _bits_of(dlc, 4)
    for byte in data:
        bits += _bits_of(byte, 8)
    if not fd:
        crc = _crc(bits, CRC15, 15, 0)
        stuffed, at, _ = _stuff(bits + _bits_of(crc, 15), after_last=True)
        tail = [1, 0, 1] + [1] * (7 + IFS_BITS)
        return WireFrame("".join(map(str, stuffed + tail)), len(stuffed), tuple(at), (), (0, 0),
                         crc, 0)
    stuffed, at, where = _stuff(bits, after_last=False)
    count = len(at)
    code = _bits_of(GRAY_PARITY[count % 8], 4)
    width = 17 if len(data) <= 16 else 21
    crc = _crc(stuffed + code, CRC17 if width == 17 else CRC21, width, 1 << (width - 1))
    out = list(stuffed)
    fixed: list[int] = []
    for i, bit in enumerate(code + _bits_of(crc, width)):
        if i % 4 == 0:
            fixed.append(len(out))
            out.append(1 - out[-1])
        out.append(bit)
    out.append(1)  # CRC delimiter
    fast_end = len(out)
    out += [0, 1] + [1] * (7 + IFS_BITS)
    phase = (where[brs_at] + 1, fast_end) if brs else (0, 0)
    return WireFrame("".join(map(str, out)), len(stuffed), tuple(at), tuple(fixed), phase,
                     crc, count)
