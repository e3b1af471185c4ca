"""A frame's time on the wire, bounded, and the payloads a patch and a force node send.

Bounds (``canbus.framebits`` has the exact count of any one frame; these contain it):

Classic CAN, n data bytes: SOF..CRC is 34 + 8n bits (11-bit id; 54 + 8n with a 29-bit id)
under stuffing, then CRC delimiter, ACK slot, ACK delimiter, EOF and intermission (13 bits).
No stuffing: 47 + 8n bits (111 for 8 bytes). Worst case: one stuff bit after the first 5
bits, then one per 4 bits, floor((34 + 8n - 1) / 4) (24 for 8 bytes: 135 bits).

CAN FD with bit rate switch (ISO 11898-1:2015, padded to a DLC length): at the nominal rate
SOF..res (16 bits, 35 with a 29-bit id), BRS, ACK slot, ACK delimiter, EOF and intermission
(12); at the data rate ESI, DLC, data, stuff count (4), CRC (17 up to 16 bytes, else 21),
6 or 7 fixed stuff bits and the CRC delimiter. Dynamic stuffing (SOF..data, none after the
last data bit) adds at most floor((16 - 1) / 4) = 3 bits before BRS and floor((22 + 8n - 2)
/ 4) in all; the worst case puts the most of them at the slower nominal rate.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from canbus.framebits import FD_LENGTHS, TAIL_BITS

if TYPE_CHECKING:
    import can


def classic_frame_bits(data_bytes: int, *, worst_case_stuffing: bool,
                       extended: bool = False) -> int:
    """Bits on the wire of one classic CAN frame (intermission included)."""
    if not 0 <= data_bytes <= 8:
        raise ValueError(f"classic CAN carries 0..8 data bytes, got {data_bytes}")
    stuffed_region = (54 if extended else 34) + 8 * data_bytes
    stuff = (stuffed_region - 1) // 4 if worst_case_stuffing else 0
    return stuffed_region + stuff + 1 + TAIL_BITS


def fd_length(data_bytes: int) -> int:
    """The smallest CAN FD payload length that holds ``data_bytes``."""
    for length in FD_LENGTHS:
        if length >= data_bytes:
            return length
    raise ValueError(f"CAN FD carries at most 64 data bytes, got {data_bytes}")


def fd_frame_bits(data_bytes: int, *, worst_case_stuffing: bool, extended: bool = False,
                  brs: bool = True) -> tuple[int, int]:
    """(nominal-rate bits, data-rate bits) of one CAN FD frame; all nominal without BRS.

    The worst case bounds the frame's *time* (for a data bitrate at least the nominal one):
    it puts as many stuff bits as can be at the nominal rate.
    """
    length = fd_length(data_bytes)
    prefix = 35 if extended else 16  # SOF..res
    stuffed = (41 if extended else 22) + 8 * length  # SOF..data
    crc = 17 if length <= 16 else 21
    nominal = prefix + 1 + TAIL_BITS
    data = (stuffed - prefix - 1) + 4 + crc + (2 + crc // 4) + 1
    if worst_case_stuffing:
        head, total = (prefix - 1) // 4, (stuffed - 2) // 4
        nominal, data = nominal + head, data + total - head
    return (nominal, data) if brs else (nominal + data, 0)


def fd_frame_time_s(data_bytes: int, nominal_bps: float, data_bps: float, *,
                    worst_case_stuffing: bool, extended: bool = False) -> float:
    """Seconds one CAN FD frame with bit rate switch occupies the bus."""
    nominal, data = fd_frame_bits(data_bytes, worst_case_stuffing=worst_case_stuffing,
                                  extended=extended)
    return nominal / nominal_bps + data / data_bps


def frame_time_s(data_bytes: int, bitrate: int, data_bitrate: int | None, *, fd: bool,
                 worst_case_stuffing: bool) -> float:
    """Seconds one 11-bit-id frame occupies the bus: classic, or CAN FD with BRS."""
    if fd:
        if data_bitrate is None:
            raise ValueError("a CAN FD frame needs a data bitrate")
        return fd_frame_time_s(data_bytes, bitrate, data_bitrate,
                               worst_case_stuffing=worst_case_stuffing)
    return classic_frame_bits(data_bytes, worst_case_stuffing=worst_case_stuffing) / bitrate


def patch_payloads(mode: str, *, fd: bool) -> list[int]:
    """Payload bytes of a patch's TPDOs for one sample.

    Classic (the EDS mappings, UNSIGNED16 codes): 3-axis 27 codes, 4 per TPDO (6 x 8 bytes +
    1 x 6); z-only 9 codes, 3 per TPDO (3 x 6). CAN FD: one TPDO with every code and the
    SYNC counter it answers (1 byte): 55 bytes (3-axis) or 19 (z-only).
    """
    values = {"z": 9, "xyz": 27}[mode]
    if fd:
        return [2 * values + 1]
    per_pdo = 3 if mode == "z" else 4
    full, rest = divmod(values, per_pdo)
    return [2 * per_pdo] * full + ([2 * rest] if rest else [])


sample_payloads = patch_payloads


def force_payloads(*, fd: bool, contact: bool = True) -> list[int]:
    """Payload bytes of a force node's PDOs for one sample, in either patch mode.

    27 INTEGER16 forces and 0x2005 (UNSIGNED16): classic 4 per PDO, 7 x 8 bytes, and the
    contact PDO (TPDO 8: net Fz, CoP x, y, state, taxels in contact) of 8 bytes; CAN FD one
    PDO with the SYNC counter too, 57 bytes, and the contact's net Fz, CoP and state: 64.
    ``contact`` False: a host whose contact summary is off (no TPDO 8).
    """
    if fd:
        return [2 * 28 + 1 + (7 if contact else 0)]
    return [8] * (8 if contact else 7)


def frame_bit_bounds(msg: can.Message, bitrate: int,
                     data_bitrate: int | None) -> tuple[float, float]:
    """Bits one frame occupies on the wire at ``bitrate``: (no stuffing, worst-case stuffing)."""
    data = 0 if msg.is_remote_frame else len(msg.data)
    if msg.is_fd:
        fast = (data_bitrate or bitrate) if msg.bitrate_switch else bitrate
        length = fd_length(data)
        return (bitrate * fd_frame_time_s(length, bitrate, fast, worst_case_stuffing=False),
                bitrate * fd_frame_time_s(length, bitrate, fast, worst_case_stuffing=True))
    best = classic_frame_bits(min(data, 8), worst_case_stuffing=False)
    worst = classic_frame_bits(min(data, 8), worst_case_stuffing=True)
    if msg.is_extended_id:
        stuffed = 34 + 20 + 8 * min(data, 8)
        best, worst = best + 20, stuffed + (stuffed - 1) // 4 + 13
    return float(best), float(worst)
