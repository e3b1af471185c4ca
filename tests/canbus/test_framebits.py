"""Frames on the wire: exact bit sequences and counts (canbus.framebits), and the planner's
bounds (canbus.busload) around them.

The oracles here are independent of the module: CRCs by polynomial long division, a decoder
that removes the stuff bits and reads the fields back, and counts derived by hand.
"""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canbus import framebits, frametime
from canbus.framebits import (
    CRC15,
    CRC17,
    CRC21,
    F_BRS,
    F_ESI,
    F_EXTENDED,
    F_FD,
    F_REMOTE,
    FD_LENGTHS,
    FrameBits,
    arbitration_key,
    bits_unchecked,
    crc15,
    fd_dlc,
    frame_bits,
    stuff_count,
)
from canbus.wireframe import WireFrame, wire_frame

GRAY = {0b000: 0, 0b001: 1, 0b011: 2, 0b010: 3, 0b110: 4, 0b111: 5, 0b101: 6, 0b100: 7}


def poly_crc(bits: str, generator: int, width: int, init: int = 0) -> int:
    """CRC as the remainder of (message * x^width + init * x^len) divided by the generator."""
    value = (int(bits or "0", 2) << width) ^ (init << len(bits))
    generator |= 1 << width
    for shift in range(value.bit_length() - 1, width - 1, -1):
        if value >> shift & 1:
            value ^= generator << (shift - width)
    return value


def destuff(bits: str, end: int) -> tuple[str, int]:
    """The bits of ``[0, end)`` without their stuff bits, and how many were removed.

    After 5 equal bits the next one must be their complement (else the frame is broken)."""
    out, removed, i, run, last = [], 0, 0, 0, ""
    while i < end:
        bit = bits[i]
        out.append(bit)
        run, last = (run + 1 if bit == last else 1), bit
        i += 1
        if run == 5 and i < end:
            assert bits[i] != bit, f"no stuff bit at {i}"
            last, run, removed, i = bits[i], 1, removed + 1, i + 1
    return "".join(out), removed


def read_back(w: WireFrame, *, fd: bool) -> dict[str, Any]:
    """Decode a frame from its wire bits, checking every fixed field and the CRC."""
    raw, removed = destuff(w.bits, w.stuffed_end)
    assert raw[0] == "0"  # SOF
    at = 12
    fields: dict[str, Any] = {"can_id": int(raw[1:12], 2), "extended": False}
    if raw[13] == "1":  # IDE recessive: a 29-bit id (SRR before it is recessive too)
        assert raw[12] == "1"
        fields["can_id"] = int(raw[1:12], 2) << 18 | int(raw[14:32], 2)
        fields["extended"], at = True, 32
    if fd:
        assert raw[at:at + (1 if fields["extended"] else 2)] == "0" * (
            1 if fields["extended"] else 2)  # RRS (and IDE)
        at += 1 if fields["extended"] else 2
        assert raw[at:at + 2] == "10"  # FDF, res
        fields["brs"], fields["esi"] = raw[at + 2] == "1", raw[at + 3] == "1"
        dlc = int(raw[at + 4:at + 8], 2)
        at += 8
        length = FD_LENGTHS[dlc]
    else:
        fields["remote"] = raw[at] == "1"
        assert raw[at + 1:at + 3] == "00"  # IDE and r0, or r1 and r0
        dlc = int(raw[at + 3:at + 7], 2)
        at += 7
        length = 0 if fields["remote"] else dlc
    fields["dlc"] = dlc
    fields["data"] = bytes(int(raw[at + 8 * k:at + 8 * k + 8], 2) for k in range(length))
    at += 8 * length
    if not fd:
        assert len(raw) == at + 15
        assert int(raw[at:], 2) == poly_crc(raw[:at], CRC15, 15) == w.crc
        tail = w.bits[w.stuffed_end:]
    else:
        assert len(raw) == at
        fixed = w.bits[w.stuffed_end:]
        width = 17 if length <= 16 else 21
        field, k, i = "", 0, 0
        while k < 4 + width:  # fixed stuff bit before the stuff count and every 4 bits
            if k % 4 == 0:
                assert fixed[i] != fixed[i - 1] if i else fixed[0] != w.bits[w.stuffed_end - 1]
                i += 1
            field += fixed[i]
            i, k = i + 1, k + 1
        count, crc = field[:4], int(field[4:], 2)
        assert GRAY[int(count[:3], 2)] == removed % 8 and count.count("1") % 2 == 0
        covered = w.bits[:w.stuffed_end] + count
        assert crc == poly_crc(covered, CRC17 if width == 17 else CRC21, width,
                               1 << (width - 1)) == w.crc
        tail = fixed[i:]
    assert tail == "1" + "0" + "1" + "1" * 7 + "111"  # CRC delim, ACK, delim, EOF, IFS
    fields["stuff"] = removed
    return fields


frames = st.fixed_dictionaries({
    "extended": st.booleans(),
    "fd": st.booleans(),
    "brs": st.booleans(),
    "esi": st.booleans(),
    "remote": st.booleans(),
    "can_id": st.integers(0, 0x1FFFFFFF),
    "data": st.lists(st.one_of(st.integers(0, 255), st.sampled_from([0, 0xFF, 0x0F, 0xF0])),
                     max_size=64).map(bytes),
    "dlc": st.integers(0, 8),
})


def _frame(f: dict[str, Any]) -> dict[str, Any]:
    """A valid frame from a drawn one: fit the id, payload and flags to the format."""
    fd, extended = bool(f["fd"]), bool(f["extended"])
    can_id = int(f["can_id"]) if extended else int(f["can_id"]) & 0x7FF
    remote = bool(f["remote"]) and not fd
    data = bytes(f["data"])
    if fd:
        data = data + bytes(FD_LENGTHS[fd_dlc(len(data))] - len(data))
    elif remote:
        data = b""
    else:
        data = data[:8]
    return {"can_id": can_id, "data": data, "extended": extended, "remote": remote,
            "dlc": f["dlc"] if remote else None, "fd": fd, "brs": fd and bool(f["brs"]),
            "esi": fd and bool(f["esi"])}


@settings(max_examples=400)
@given(frames)
def test_the_fast_count_is_the_length_of_the_exact_bit_sequence(drawn: dict[str, Any]) -> None:
    f = _frame(drawn)
    w = wire_frame(**f)
    assert frame_bits(**f) == w.counts
    assert w.counts.total == len(w.bits)


# Bytes whose bit runs reach 5 inside a byte or across bytes and 16-bit words: the
# table-driven count carries its stuffing state across every boundary.
RUNNY = st.sampled_from([0x00, 0xFF, 0x0F, 0xF0, 0x1F, 0xF8, 0x07, 0xE0, 0x7C, 0x83, 0x3E])
PAYLOAD_BYTE = st.one_of(st.integers(0, 255), RUNNY)


@st.composite
def classic_frames(draw: st.DrawFn) -> tuple[int, int, int, bytes]:
    """(id, flags, DLC, payload) of any classic frame, every length 0..8 as likely."""
    extended, remote = draw(st.booleans()), draw(st.booleans())
    can_id = draw(st.integers(0, 0x1FFFFFFF if extended else 0x7FF))
    dlc = draw(st.integers(0, 8))
    data = b"" if remote else bytes(draw(st.lists(PAYLOAD_BYTE, min_size=dlc, max_size=dlc)))
    return can_id, F_EXTENDED * extended | F_REMOTE * remote, dlc, data


@st.composite
def fd_frames(draw: st.DrawFn) -> tuple[int, int, bytes]:
    """(id, flags, payload) of any CAN FD frame, every DLC length as likely."""
    extended = draw(st.booleans())
    can_id = draw(st.integers(0, 0x1FFFFFFF if extended else 0x7FF))
    flags = (F_FD | F_EXTENDED * extended | F_BRS * draw(st.booleans())
             | F_ESI * draw(st.booleans()))
    length = draw(st.sampled_from(FD_LENGTHS))
    return can_id, flags, bytes(draw(st.lists(PAYLOAD_BYTE, min_size=length, max_size=length)))


@settings(max_examples=500)
@given(classic_frames())
def test_the_wires_count_of_a_classic_frame_is_its_exact_bit_sequence(
        frame: tuple[int, int, int, bytes]) -> None:
    can_id, flags, dlc, data = frame
    exact = wire_frame(can_id, data, extended=bool(flags & F_EXTENDED),
                       remote=bool(flags & F_REMOTE), dlc=dlc).counts
    assert bits_unchecked(can_id, flags, dlc, data) == exact
    # a can.Message's payload is a bytearray: the same count
    assert bits_unchecked(can_id, flags, dlc, bytearray(data)) == exact


@settings(max_examples=300)
@given(fd_frames())
def test_the_wires_count_of_a_can_fd_frame_is_its_exact_bit_sequence(
        frame: tuple[int, int, bytes]) -> None:
    can_id, flags, data = frame
    exact = wire_frame(can_id, data, extended=bool(flags & F_EXTENDED), fd=True,
                       brs=bool(flags & F_BRS), esi=bool(flags & F_ESI)).counts
    assert bits_unchecked(can_id, flags, len(data), data) == exact
    assert bits_unchecked(can_id, flags, len(data), bytearray(data)) == exact


def test_a_stuff_bit_every_4_payload_bits_is_counted() -> None:
    # 00111100 repeated: the DLC (1000) ends on 3 zeros, so the payload's first 2 zeros make
    # a run of 5; from then on every group of 4 equal bits joins the stuff bit before it into
    # a run of 5. A stuff bit every 4 bits: 16 in 64, the most a payload can take, so the
    # fast count's four 16-bit words each hold 4, whatever the id before them.
    for can_id in (0, 0x123, 0x2AA, 0x7FF):
        w = wire_frame(can_id, b"\x3c" * 8)
        in_payload = [k for k, at in enumerate(w.stuff_at) if 19 <= at - k - 1 < 19 + 64]
        assert len(in_payload) == 16
        assert frame_bits(can_id, b"\x3c" * 8) == w.counts
        for byte in (0xF0, 0x78, 0x1E, 0x0F, 0x87, 0xC3, 0xE1):  # the other phases
            data = bytes([byte]) * 8
            assert frame_bits(can_id, data) == wire_frame(can_id, data).counts


def test_counts_stay_exact_when_the_header_cache_is_refilled() -> None:
    # more distinct headers than the cache holds: it is emptied and filled again
    count = framebits._MAX_HEADS + 100
    data = bytes([0x0F, 0x80, 0x00, 0x3E, 0xFF, 0x01, 0xF0, 0x55])
    counted = [bits_unchecked(0x1000000 + k * 997, F_EXTENDED, 8, data) for k in range(count)]
    assert len(framebits._HEADS) <= framebits._MAX_HEADS
    for k in range(0, count, 389):
        assert counted[k] == wire_frame(0x1000000 + k * 997, data, extended=True).counts


@settings(max_examples=300)
@given(frames)
def test_unstuffing_the_wire_bits_gives_the_frame_back(drawn: dict[str, Any]) -> None:
    f = _frame(drawn)
    w = wire_frame(**f)
    back = read_back(w, fd=bool(f["fd"]))
    assert back["can_id"] == f["can_id"] and back["extended"] == f["extended"]
    assert back["data"] == f["data"]
    assert back["stuff"] == len(w.stuff_at) == w.counts.stuff
    if f["fd"]:
        assert (back["brs"], back["esi"]) == (f["brs"], f["esi"])
        assert back["dlc"] == fd_dlc(len(f["data"]))
    else:
        assert back["remote"] == f["remote"]


@settings(max_examples=300)
@given(frames)
def test_no_six_equal_bits_from_sof_to_the_end_of_the_crc(drawn: dict[str, Any]) -> None:
    f = _frame(drawn)
    w = wire_frame(**f)
    crc_end = len(w.bits) - 13  # CRC delimiter, ACK slot and delimiter, EOF, intermission
    assert "000000" not in w.bits[:crc_end] and "111111" not in w.bits[:crc_end]


@settings(max_examples=400)
@given(frames, st.sampled_from([1_000_000, 500_000]), st.sampled_from([1, 2, 5, 8]))
def test_the_planners_bounds_contain_every_frame(drawn: dict[str, Any], bitrate: int,
                                                  ratio: int) -> None:
    f = _frame(drawn)
    exact = frame_bits(**f)
    n = len(f["data"])
    extended = bool(f["extended"])
    if not f["fd"]:
        low = frametime.classic_frame_bits(n, worst_case_stuffing=False, extended=extended)
        high = frametime.classic_frame_bits(n, worst_case_stuffing=True, extended=extended)
        assert low <= exact.total <= high
        return
    brs, fast = bool(f["brs"]), bitrate * ratio
    best = frametime.fd_frame_bits(n, worst_case_stuffing=False, extended=extended, brs=brs)
    worst = frametime.fd_frame_bits(n, worst_case_stuffing=True, extended=extended, brs=brs)
    assert sum(best) <= exact.total <= sum(worst)
    assert best[0] <= exact.nominal <= worst[0]

    def seconds(bits: tuple[int, int]) -> float:
        return bits[0] / bitrate + bits[1] / fast

    assert seconds(best) <= exact.duration_s(bitrate, fast) + 1e-15
    assert exact.duration_s(bitrate, fast) <= seconds(worst) + 1e-15


def _arbitration_bits(can_id: int, extended: bool, remote: bool) -> str:
    """The arbitration field as it goes on the wire (stuff bits aside)."""
    if extended:
        return f"{can_id >> 18:011b}11{can_id & 0x3FFFF:018b}{int(remote)}"
    return f"{can_id:011b}{int(remote)}0"  # id, RTR, IDE


@given(st.tuples(st.integers(0, 0x1FFFFFFF), st.booleans(), st.booleans()),
       st.tuples(st.integers(0, 0x1FFFFFFF), st.booleans(), st.booleans()))
def test_the_smaller_key_wins_bitwise_arbitration(
        a: tuple[int, bool, bool], b: tuple[int, bool, bool]) -> None:
    a = (a[0] if a[1] else a[0] & 0x7FF, a[1], a[2])
    b = (b[0] if b[1] else b[0] & 0x7FF, b[1], b[2])
    bits_a, bits_b = _arbitration_bits(*a), _arbitration_bits(*b)
    common = min(len(bits_a), len(bits_b))  # a dominant 0 wins at the first difference
    ka = arbitration_key(a[0], extended=a[1], remote=a[2])
    kb = arbitration_key(b[0], extended=b[1], remote=b[2])
    if bits_a[:common] == bits_b[:common]:
        assert ka == kb and bits_a == bits_b
    else:
        assert (ka < kb) == (bits_a[:common] < bits_b[:common])


def test_crcs_match_the_catalogued_check_values() -> None:
    # The CRC RevEng catalogue's check values (CRC of the ASCII bytes "123456789", register
    # from 0): CRC-15/CAN 0x059E, CRC-17/CAN-FD 0x04F03, CRC-21/CAN-FD 0x0ED841.
    message = "".join(f"{c:08b}" for c in b"123456789")
    assert crc15(b"123456789") == 0x059E == poly_crc(message, CRC15, 15)
    assert poly_crc(message, CRC17, 17) == 0x04F03
    assert poly_crc(message, CRC21, 21) == 0x0ED841
    assert wire_frame(0x123, b"\x01\x02").crc == poly_crc(
        "0" + f"{0x123:011b}" + "000" + "0010" + "0000000100000010", CRC15, 15)


def test_hand_counted_classic_frames() -> None:
    # id 0, no data: SOF..DLC are 19 zeros and CRC-15 of zeros is 0: 34 zeros under stuffing,
    # a stuff bit after every 5 (6 of them, the last group has 4), + 13 = 53 bits.
    assert frame_bits(0, b"") == FrameBits(53, 0, 6)
    # id 0, 8 zero bytes: SOF, id, RTR, IDE, r0 = 15 zeros -> 3 stuff bits, the third a 1
    # that runs into the DLC's 1 (1000); then 3 + 64 = 67 zeros -> 13 stuff bits (67 = 13*5
    # + 2); CRC 0x145B = 001010001011011 after those 2 zeros makes no run of 5. 16 stuff
    # bits: 34 + 64 + 16 + 13 = 127.
    zeros = wire_frame(0, bytes(8))
    assert zeros.crc == 0x145B and frame_bits(0, bytes(8)) == FrameBits(127, 0, 16)
    assert zeros.stuff_at == (5, 11, 17, 24, 30, 36, 42, 48, 54, 60, 66, 72, 78, 84, 90, 96)
    # id 0x2AA (01010101010) and 0xAA bytes: the longest run is RTR, IDE, r0 after the id's
    # last 0 (4 zeros); CRC 0x43D6 = 100001111010110 has runs of 4 at most: no stuffing,
    # 47 + 64 = 111 bits, the best case.
    assert wire_frame(0x2AA, b"\xaa" * 8).crc == 0x43D6
    assert frame_bits(0x2AA, b"\xaa" * 8) == FrameBits(111, 0, 0)
    assert frame_bits(0x2AA, b"\xaa" * 8).duration_s(1_000_000) == pytest.approx(111e-6)


def test_hand_counted_can_fd_frames() -> None:
    # id 0, no data, BRS: SOF, id, RRS, IDE = 14 zeros -> 2 stuff bits (after 5 and 10); FDF 1,
    # res 0, BRS 1, then ESI 0 and DLC 0000 end on 5 zeros but it is the last bit: the fixed
    # stuff bit before the stuff count does the job. Nominal: SOF..BRS 17 + 2 stuff + ACK 2 +
    # EOF 7 + IFS 3 = 31; data phase: ESI + DLC 5, fixed stuff + stuff count 5, CRC-17 with 5
    # fixed stuff bits 22, CRC delimiter 1 = 33.
    empty = wire_frame(0, b"", fd=True, brs=True)
    assert empty.counts == frame_bits(0, b"", fd=True, brs=True) == FrameBits(31, 33, 2)
    assert empty.stuff_count == 2 and len(empty.fixed_stuff_at) == 6
    # id 0, 64 zero bytes, BRS: 2 stuff bits in the id as above; DLC 1111 (64 bytes), then
    # 512 zeros -> 102 stuff bits (512 = 102*5 + 2). Data phase: 1 + 4 + 512 + 102 + 4 +
    # CRC-21 21 + 7 fixed + 1 = 652 bits; at 1 / 5 Mbit/s: 31 us + 130.4 us.
    full = frame_bits(0, bytes(64), fd=True, brs=True)
    assert full == FrameBits(31, 652, 104)
    assert full.duration_s(1_000_000, 5_000_000) == pytest.approx(31e-6 + 652 / 5e6)
    # without BRS the same bits all go at the nominal rate
    assert frame_bits(0, bytes(64), fd=True) == FrameBits(683, 0, 104)


def test_stuff_count_follows_runs_across_stuff_bits() -> None:
    # 5 zeros, then 1111 0000 ...: after the first stuff bit each group of 4 joins the stuff
    # bit before it into a run of 5: one stuff bit per 4 bits, the worst case (25 - 1) // 4.
    worst = "00000" + "11110000" * 2 + "1111"
    assert stuff_count(int(worst, 2), len(worst)) == 6 == (len(worst) - 1) // 4
    assert stuff_count(int("0" * 10, 2), 10) == 2
    assert stuff_count(int("0" * 10, 2), 10, after_last=False) == 1


def test_bad_frames_are_refused() -> None:
    with pytest.raises(ValueError, match="out of range"):
        frame_bits(0x800, b"")
    with pytest.raises(ValueError, match="no remote frames"):
        frame_bits(0x100, b"", fd=True, remote=True)
    with pytest.raises(ValueError, match="at most 64"):
        frame_bits(0x100, bytes(65), fd=True)
    with pytest.raises(ValueError, match=r"DLC is 0\.\.8"):
        frame_bits(0x100, bytes(9))
