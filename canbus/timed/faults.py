"""Fault confinement (ISO 11898-1) and injected bit errors on a timed wire.

Counters: a transmitter's TEC rises by 8 per error frame on its frame and falls by 1 per frame
sent; a receiver's REC rises by 1 per error it sees and falls by 1 per frame received (from
above 127 it drops to 127, within ISO's 119..127). A node is error passive while TEC or REC
is above 127 (its CAN FD frames then carry ESI recessive, and after transmitting it waits 8
more bit times, suspend transmission, before it starts another frame) and bus off once TEC
exceeds 255: it neither sends nor receives until it has seen 128 sequences of 11 recessive
bits (each frame or error frame ends with one; an idle bus gives one every 11 bit times),
then it is error active again with both counters at 0. Its transmit queue is kept.

Acknowledgement: a frame is acknowledged when at least one other node that is not bus off,
acknowledges (``acknowledge=True``) and understands the frame (CAN FD frames need an FD node)
is on the wire. Otherwise its transmitter sees an ACK error: an error frame, TEC + 8, and the
frame is sent again; an error-passive transmitter's ACK error does not raise its TEC (ISO's
exception), so a node alone on the wire settles error passive and keeps retransmitting, as on
a real bus. Receivers' REC is not changed by an ACK error (their frame was fine until the
transmitter's error flag), and the frame is delivered to no one.

Bit errors: each attempt of a frame whose transmitter has ``error_probability`` p > 0 is hit
with probability p; the error is detected at a uniformly drawn bit between SOF and the ACK
delimiter, an error flag (6 bits) and error delimiter (8) follow, then the intermission. All
nodes see it: TEC + 8 for the transmitter, REC + 1 for every receiver; the frame is sent again
(automatic retransmission, at the next arbitration like any other frame).
"""

from __future__ import annotations

import random

from canbus.framebits import IFS_BITS, TAIL_BITS, FrameBits

ERROR_FRAME_BITS = 6 + 8
"""Error flag and error delimiter, at the nominal rate."""
SUSPEND_BITS = 8
RECOVERY_SEQUENCES, RECOVERY_RUN_BITS = 128, 11
PASSIVE_ABOVE, BUS_OFF_ABOVE = 127, 255


class BitErrors:
    """Injected bit errors: probability per attempt, and where in the frame they strike."""

    def __init__(self, probability: float, seed: int | None) -> None:
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"error_probability must be in 0..1, got {probability}")
        self.probability = probability
        self.rng = random.Random(seed)

    def hit(self) -> bool:
        return self.probability > 0.0 and self.rng.random() < self.probability

    def error_time_s(self, bits: FrameBits, bit_s: float, data_bit_s: float) -> float:
        """Time from SOF to the end of the bit at which the error is detected (drawn)."""
        checked = bits.total - (TAIL_BITS - 2)  # SOF..ACK delimiter: not EOF, not intermission
        k = self.rng.randrange(checked) + 1
        return through_bit(bits, k, bit_s, data_bit_s)


def through_bit(bits: FrameBits, k: int, bit_s: float, data_bit_s: float) -> float:
    """Seconds from SOF to the end of the frame's ``k``-th bit (1-based), phase by phase."""
    head = bits.nominal - TAIL_BITS if bits.data else bits.total
    if k <= head:
        return k * bit_s
    if k <= head + bits.data:
        return head * bit_s + (k - head) * data_bit_s
    return head * bit_s + bits.data * data_bit_s + (k - head - bits.data) * bit_s


def ack_error_time_s(bits: FrameBits, bit_s: float, data_bit_s: float) -> float:
    """Time from SOF to the end of the ACK slot; the error flag starts at the delimiter."""
    return through_bit(bits, bits.total - (TAIL_BITS - 1), bit_s, data_bit_s)


def error_frame_s(bit_s: float) -> float:
    """Error flag, error delimiter and intermission."""
    return (ERROR_FRAME_BITS + IFS_BITS) * bit_s
