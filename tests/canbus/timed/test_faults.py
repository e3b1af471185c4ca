"""Fault injection on the timed wire: bit errors, bus off and recovery, overflow, no ACK."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import can
import pytest

from canbus.framebits import frame_bits
from canbus.timed import TimedBus, TimedBusConfigError

OpenBus = Callable[..., TimedBus]
US = 1e-6
STAMP = 5e-7  # timestamps are floats near 1.8e9 s: 0.24 us resolution


def frame(can_id: int, data: bytes = b"", **kwargs: Any) -> can.Message:
    kwargs.setdefault("is_extended_id", False)
    return can.Message(arbitration_id=can_id, data=data, **kwargs)


def test_frames_hit_by_bit_errors_are_retransmitted_and_arrive_once(open_bus: OpenBus) -> None:
    a = open_bus(error_probability=0.3, error_seed=7)
    b, c = open_bus(), open_bus()
    for k in range(200):
        a.send(frame(0x181, k.to_bytes(2, "little") + bytes(6)))
    got = [b.recv(1.0) for _ in range(200)]
    assert all(m is not None for m in got)
    assert [int.from_bytes(m.data[:2], "little") for m in got if m] == list(range(200))
    assert b.recv(0) is None
    assert len([c.recv(1.0) for _ in range(200)]) == 200
    stats = b.wire_stats()
    assert 30 < stats.error_frames < 100  # about 0.3 / 0.7 per frame delivered
    assert stats.retransmissions == stats.error_frames and stats.frames == 200
    sender = a.node_stats()
    assert sender.sent == 200 and sender.errors == stats.error_frames
    # every attempt holds the wire: frames plus error frames (at least flag, delimiter, IFS)
    frames_s = sum(frame_bits(0x181, m.data).total for m in got if m) * US
    assert stats.busy_s >= frames_s + stats.error_frames * 17 * US
    assert stats.busy_s <= frames_s + stats.error_frames * (135 + 17) * US
    # TEC: +8 per error, -1 per frame sent; 0.3 / 0.7 * 8 > 1: it climbs (error passive)
    assert sender.tec > 127 and sender.state == can.BusState.PASSIVE
    a.error_probability = 0.0
    for _ in range(sender.tec):  # every frame sent without error takes 1 off
        a.send(frame(0x181))
    assert len([b.recv(1.0) for _ in range(sender.tec)]) == sender.tec
    assert a.node_stats().tec == 0 and a.state == can.BusState.ACTIVE


def test_bus_off_after_32_errors_and_back_after_128_x_11_recessive_bits(
        open_bus: OpenBus) -> None:
    a = open_bus(error_probability=1.0, error_seed=1)
    b = open_bus(receive_error_frames=True)
    msg = frame(0x2AA, b"\xaa" * 8)  # 111 bits, no stuffing
    a.send(msg)
    errors = []
    for k in range(1, 33):
        error = b.recv(1.0)
        assert error is not None and error.is_error_frame
        errors.append(error)
        node = a.node_stats()
        assert node.tec == 8 * k and b.node_stats().rec == k
        expected = (can.BusState.ERROR if k == 32 else can.BusState.PASSIVE if k >= 16
                    else can.BusState.ACTIVE)
        assert node.state == expected == a.state
    assert a.node_stats().bus_off_count == 1
    a.error_probability = 0.0
    (back,) = [b.recv(1.0)]
    assert back is not None and not back.is_error_frame and back.data == msg.data
    # the last error frame ended (delimiter + 3 intermission bits) at errors[-1] + 3 us;
    # bus off lasts 128 sequences of 11 recessive bits on the idle wire: 1408 us; then the
    # frame: 111 bits, delivered at the end of its EOF.
    assert back.timestamp - errors[-1].timestamp == pytest.approx(
        3 * US + 1408 * US + 111 * US - 3 * US, abs=STAMP)
    node = a.node_stats()
    assert node.state == can.BusState.ACTIVE and node.tec == 0 and node.sent == 1


def test_a_bus_off_node_neither_sends_nor_receives(open_bus: OpenBus) -> None:
    a = open_bus(error_probability=1.0)
    b, c = open_bus(receive_error_frames=True), open_bus()
    a.send(frame(0x100))
    for _ in range(32):
        assert b.recv(1.0) is not None
    assert a.state == can.BusState.ERROR
    c.send(frame(0x200))  # frames go on while a is off: they count towards its recovery
    got = b.recv(1.0)
    assert got is not None and got.arbitration_id == 0x200
    assert a.recv(0) is None and a.node_stats().received == 0


def test_a_full_receive_queue_loses_frames_there_only(open_bus: OpenBus) -> None:
    a = open_bus()
    small = open_bus(rx_queue_size=5)
    other = open_bus()
    for k in range(20):
        a.send(frame(0x180 + k))
    assert len([other.recv(1.0) for _ in range(20)]) == 20
    stats = small.node_stats()
    assert (stats.received, stats.lost_overflow) == (5, 15)
    kept = [small.recv(0) for _ in range(5)]
    assert [m.arbitration_id for m in kept if m] == [0x180 + k for k in range(5)]
    assert small.recv(0) is None


def test_without_an_acknowledging_node_the_sender_retries_error_passive(
        open_bus: OpenBus) -> None:
    a = open_bus()
    deaf = open_bus(acknowledge=False)
    a.send(frame(0x123, b"\x01"))
    assert deaf.recv(0.05) is None  # 50 ms of simulated time: no frame, only ACK errors
    node = a.node_stats()
    # +8 per ACK error up to error passive at 128; ISO: no more once passive, never bus off
    assert node.state == can.BusState.PASSIVE and node.tec == 128
    stats = deaf.wire_stats()
    # an attempt: through the ACK slot + error flag and delimiter + intermission; 16 of them
    # back to back, then one every attempt + 8 bits (error passive: suspend transmission)
    attempt = (frame_bits(0x123, b"\x01").total - 11 + 14 + 3) * US
    passive_from = 16 * attempt + 8 * US
    assert stats.error_frames == 16 + int((0.05 - passive_from) // (attempt + 8 * US)) + 1
    deaf.acknowledge = True
    got = deaf.recv(1.0)
    assert got is not None and got.data == b"\x01"
    assert deaf.recv(0.01) is None  # delivered once
    assert a.node_stats().tec == 127 and a.state == can.BusState.ACTIVE


def test_a_node_alone_retries_until_another_joins(open_bus: OpenBus) -> None:
    alone = open_bus()
    alone.send(frame(0x321))
    assert alone.recv(0.01) is None
    assert alone.wire_stats().error_frames >= 16 and alone.state == can.BusState.PASSIVE
    late = open_bus()
    got = late.recv(1.0)
    assert got is not None and got.arbitration_id == 0x321


def test_a_node_alone_in_real_time_waits_without_spinning(open_bus: OpenBus) -> None:
    import time

    alone = open_bus(realtime=True)
    alone.send(frame(0x321))
    time.sleep(0.05)  # pacing: the wire's clock (the machine's) passes; retries fall due
    first = alone.wire_stats()
    time.sleep(0.05)  # pacing: as above
    second = alone.wire_stats()
    assert alone.state == can.BusState.PASSIVE
    # the retries are counted as time passes, not played one by one by the wire's thread
    assert alone._wire.stuck is not None and alone._wire._next_time() is None
    assert second.error_frames - first.error_frames > 100
    # an attempt: through the ACK slot, error flag and delimiter, intermission; then the
    # error-passive sender suspends 8 bit times, when the wire is idle
    attempt = frame_bits(0x321, b"").total - 11 + 14 + 3
    assert second.load_since(first) == pytest.approx(100 * attempt / (attempt + 8), abs=1.0)


def test_fault_options_are_checked(open_bus: OpenBus) -> None:
    with pytest.raises(TimedBusConfigError, match="error_probability"):
        open_bus(error_probability=1.5)
    bus = open_bus()
    with pytest.raises(ValueError, match="error_probability"):
        bus.error_probability = -0.1
