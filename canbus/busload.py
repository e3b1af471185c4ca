"""Bus-load planner: CAN frame bit counts and the load N patches put on a bus.

Classic CAN data frame with an 11-bit identifier and n data bytes:
SOF 1 + identifier 11 + RTR 1 + IDE 1 + r0 1 + DLC 4 + data 8n + CRC 15 = 34 + 8n bits
are subject to bit stuffing; CRC delimiter 1 + ACK 2 + EOF 7 + intermission 3 = 13 bits
are not. Without stuffing a frame is 47 + 8n bits (111 for 8 bytes). Worst-case stuffing
adds one bit per 4 after the first stuffed bit: floor((34 + 8n - 1) / 4) bits (24 for
8 bytes, 135 in all). At 1 Mbit/s that is 7,407 to 9,009 frames/s of 8 bytes.

CAN FD (11-bit identifier, ISO CRC): the arbitration phase (SOF, identifier, RRS, IDE,
FDF, res, BRS = 17 bits, plus stuffing) and the tail (CRC delimiter, ACK, EOF,
intermission = 12 bits) run at the nominal bitrate; ESI, DLC, data, stuff count and CRC
run at the data bitrate. The fixed stuff bits of the CRC field (one per 4 bits) are
counted; dynamic stuffing is counted in the worst case only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


def classic_frame_bits(data_bytes: int, *, worst_case_stuffing: bool) -> int:
    """Bits on the wire of one classic CAN frame with an 11-bit identifier."""
    if not 0 <= data_bytes <= 8:
        raise ValueError(f"classic CAN carries 0..8 data bytes, got {data_bytes}")
    stuffed_region = 34 + 8 * data_bytes
    stuff = (stuffed_region - 1) // 4 if worst_case_stuffing else 0
    return stuffed_region + stuff + 13


def fd_length(data_bytes: int) -> int:
    """The smallest CAN FD payload length that holds ``data_bytes``."""
    for length in FD_LENGTHS:
        if length >= data_bytes:
            return length
    raise ValueError(f"CAN FD carries at most 64 data bytes, got {data_bytes}")


def fd_frame_time_s(data_bytes: int, nominal_bps: float, data_bps: float, *,
                    worst_case_stuffing: bool) -> float:
    """Seconds one CAN FD frame (11-bit identifier, bit-rate switch) occupies the bus."""
    length = fd_length(data_bytes)
    crc_bits = 17 if length <= 16 else 21
    arbitration = 17
    data_phase = 1 + 4 + 8 * length + 4 + crc_bits  # ESI, DLC, data, stuff count, CRC
    data_phase += math.ceil((4 + crc_bits) / 4)  # fixed stuff bits in stuff count and CRC
    if worst_case_stuffing:
        arbitration += (arbitration - 1) // 4
        data_phase += (1 + 4 + 8 * length - 1) // 4
    return (arbitration + 12) / nominal_bps + data_phase / data_bps


@dataclass(frozen=True)
class Plan:
    """Bus load of ``patches`` patches each sending ``frames_per_sample`` frames per sample."""

    patches: int
    rate_hz: float
    mode: str
    bitrate: int
    data_bitrate: int | None
    frames_per_sample: int
    frames_per_s: float
    load_best_pct: float
    load_worst_pct: float
    target_pct: float
    max_rate_hz: float

    @property
    def over_target(self) -> bool:
        return self.load_worst_pct > self.target_pct


def sample_payloads(mode: str, *, fd: bool) -> list[int]:
    """Payload bytes of the TPDOs of one sample (the EDS mappings: 2 bytes per value)."""
    values = {"z": 9, "xyz": 27}[mode]
    if fd:
        return [2 * values]
    per_pdo = 3 if mode == "z" else 4
    full, rest = divmod(values, per_pdo)
    return [2 * per_pdo] * full + ([2 * rest] if rest else [])


def plan(patches: int, rate_hz: float, mode: str, bitrate: int, *,
         data_bitrate: int | None = None, target_pct: float = 70.0) -> Plan:
    """Bus load in %, frames/s and the largest sample rate under ``target_pct``."""
    fd = data_bitrate is not None
    payloads = sample_payloads(mode, fd=fd)

    def sample_time(worst: bool) -> float:
        if data_bitrate is not None:
            return sum(fd_frame_time_s(n, bitrate, data_bitrate, worst_case_stuffing=worst)
                       for n in payloads)
        return sum(classic_frame_bits(n, worst_case_stuffing=worst) for n in payloads) / bitrate

    best, worst = sample_time(False), sample_time(True)
    return Plan(
        patches=patches, rate_hz=rate_hz, mode=mode, bitrate=bitrate,
        data_bitrate=data_bitrate, frames_per_sample=len(payloads),
        frames_per_s=patches * rate_hz * len(payloads),
        load_best_pct=100.0 * patches * rate_hz * best,
        load_worst_pct=100.0 * patches * rate_hz * worst,
        target_pct=target_pct,
        max_rate_hz=target_pct / 100.0 / (patches * worst),
    )
