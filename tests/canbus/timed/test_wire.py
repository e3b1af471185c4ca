"""The timed wire: arbitration under contention, exact frame times, the clock."""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canbus.timed import TimedBus
from canbus.timed.stats import LoadWindow
from tests.canbus.timed.stamps import check_starts
from tests.support.rigs.waiting import wait_until

OpenBus = Callable[..., TimedBus]
US = 1e-6
IFS = 3 * US  # at 1 Mbit/s
STAMP = 5e-7  # a float time.time() near 1.8e9 s resolves 0.24 us: timestamps are that exact


def frame(can_id: int, data: bytes = b"", **kwargs: Any) -> can.Message:
    kwargs.setdefault("is_extended_id", False)
    return can.Message(arbitration_id=can_id, data=data, **kwargs)


def drain(bus: can.BusABC, n: int, timeout: float = 1.0) -> list[can.Message]:
    out = []
    for _ in range(n):
        msg = bus.recv(timeout)
        assert msg is not None, f"only {len(out)} of {n} frames arrived"
        out.append(msg)
    return out


def ids(msgs: list[can.Message]) -> list[int]:
    return [m.arbitration_id for m in msgs]


# Frames whose bits are counted by hand in tests/canbus/test_framebits.py, at 1 / 5 Mbit/s:
ZEROS_8 = (frame(0, bytes(8)), 127 * US)  # 16 stuff bits
ALTERNATING_8 = (frame(0x2AA, b"\xaa" * 8), 111 * US)  # no stuff bit
EMPTY = (frame(0), 53 * US)  # 6 stuff bits
FD_ZEROS_64 = (frame(0, bytes(64), is_fd=True, bitrate_switch=True), 31 * US + 652 / 5e6)
FD_EMPTY = (frame(0, is_fd=True, bitrate_switch=True), 31 * US + 33 / 5e6)
FD_ZEROS_64_NO_BRS = (frame(0, bytes(64), is_fd=True), 683 * US)


def test_frames_under_contention_go_by_arbitration(open_bus: OpenBus) -> None:
    a, b, c, d, listener = (open_bus() for _ in range(5))
    a.send(frame(0x7F0, bytes(8)))  # alone on an idle wire: it starts at once
    listener.advance(10 * US)  # ... and is still on the wire while the others queue
    b.send(frame(0x300, b"b"))
    c.send(frame(0x100, b"c"))
    d.send(frame(0x200, b"d"))
    a.send(frame(0x050, b"a"))  # behind a's first frame in a's queue, then lowest id
    got = drain(listener, 5)
    assert ids(got) == [0x7F0, 0x050, 0x100, 0x200, 0x300]


def test_a_node_sends_in_fifo_order(open_bus: OpenBus) -> None:
    a, b, listener = open_bus(), open_bus(), open_bus()
    a.send(frame(0x300))
    a.send(frame(0x100))  # FIFO: waits behind 0x300 although its id is lower
    b.send(frame(0x200))
    assert ids(drain(listener, 3)) == [0x200, 0x300, 0x100]


def test_base_and_extended_ids_and_remote_frames_arbitrate_as_on_the_wire(
        open_bus: OpenBus) -> None:
    listener = open_bus()
    blocker = open_bus()
    blocker.send(frame(0x7FF, bytes(8)))
    listener.advance(10 * US)
    queued = [
        frame(0x100 << 18 | 5, is_extended_id=True),  # same 11 leading bits, SRR/IDE lose
        frame(0x100, is_remote_frame=True, dlc=2),  # RTR recessive loses to the data frame
        frame(0x100, b"\x01"),
        frame(0x0FF << 18 | 0x3FFFF, is_extended_id=True),  # smaller base id wins outright
        frame(0x100 << 18 | 5, is_extended_id=True, is_remote_frame=True),
        frame(0x100 << 18 | 4, is_extended_id=True),
    ]
    for msg in queued:
        open_bus().send(msg)
    got = drain(listener, 7)[1:]
    assert [(m.arbitration_id, m.is_extended_id, m.is_remote_frame) for m in got] == [
        (0x0FF << 18 | 0x3FFFF, True, False),
        (0x100, False, False),
        (0x100, False, True),
        (0x100 << 18 | 4, True, False),
        (0x100 << 18 | 5, True, False),
        (0x100 << 18 | 5, True, True),
    ]


def test_frames_take_their_hand_counted_time_back_to_back(open_bus: OpenBus) -> None:
    a = open_bus(fd=True, data_bitrate=5_000_000)
    b = open_bus(fd=True)  # takes the channel's data bitrate
    sent = [ZEROS_8, ALTERNATING_8, FD_ZEROS_64, EMPTY, FD_EMPTY, FD_ZEROS_64_NO_BRS]
    start = a.now()
    for msg, _ in sent:
        a.send(msg)
    got = drain(b, len(sent))
    assert ids(got) == [0, 0x2AA, 0, 0, 0, 0]
    # the first frame starts at once and is delivered at the end of its EOF
    assert got[0].timestamp == pytest.approx(start + sent[0][1] - IFS, abs=STAMP)
    for k in range(1, len(sent)):  # each next frame: its whole duration later
        assert got[k].timestamp - got[k - 1].timestamp == pytest.approx(sent[k][1], abs=STAMP)
    assert got[2].data == bytes(64) and got[2].is_fd and got[2].bitrate_switch
    assert all(m.is_rx and m.channel == a.channel_id for m in got)


def test_fd_payloads_are_padded_to_a_dlc_length(open_bus: OpenBus) -> None:
    a, b = open_bus(fd=True), open_bus(fd=True)
    a.send(frame(0x181, b"\x01" * 55, is_fd=True, bitrate_switch=True))
    (msg,) = drain(b, 1)
    assert msg.data == b"\x01" * 55 + bytes(9) and msg.dlc == 64


def test_idle_wire_starts_a_frame_when_it_is_sent(open_bus: OpenBus) -> None:
    a, b = open_bus(), open_bus()
    start = a.now()
    a.send(ZEROS_8[0])
    b.advance(1e-3)  # the wire idles after the frame
    a.send(ALTERNATING_8[0])
    first, second = drain(b, 2)
    assert first.timestamp == pytest.approx(start + 127 * US - IFS, abs=STAMP)
    assert second.timestamp == pytest.approx(start + 1e-3 + 111 * US - IFS, abs=STAMP)
    stats = b.wire_stats()
    assert stats.frames == 2 and stats.nominal_bits == 127 + 111 and stats.data_bits == 0
    # busy up to the clock, which stands at the end of the second EOF: its intermission
    # (3 bits) is still ahead. Kept as time since the wire started: exact.
    assert stats.busy_s == pytest.approx((238 - 3) * US, abs=1e-12)


def test_real_time_frames_arrive_after_their_end_stamped_exactly(open_bus: OpenBus) -> None:
    a, b = open_bus(realtime=True), open_bus(realtime=True)
    sent = []
    for _ in range(20):
        before = a.now()
        a.send(ZEROS_8[0])
        sent.append((before, a.now()))
    arrivals, got = [], []
    for _ in range(20):
        msg = b.recv(2.0)
        assert msg is not None
        arrivals.append(time.time())
        got.append(msg)
    # back to back on the wire's clock (unless this thread was held up longer than a frame),
    # whatever the readers' wake-ups
    check_starts([m.timestamp for m in got], sent, 127, 1_000_000)
    assert all(arrived >= msg.timestamp for arrived, msg in zip(arrivals, got, strict=True))
    assert got[-1].timestamp <= arrivals[-1]


def test_real_time_contention_while_a_slow_frame_is_on_the_wire(open_bus: OpenBus) -> None:
    slow = {"realtime": True, "bitrate": 10_000}  # an 8-byte frame holds the wire ~12 ms
    a, b, c, listener = (open_bus(**slow) for _ in range(4))
    a.send(frame(0x7F0, bytes(8)))
    b.send(frame(0x300))
    c.send(frame(0x100))
    a.send(frame(0x050))
    assert ids(drain(listener, 4)) == [0x7F0, 0x050, 0x100, 0x300]


def test_own_frames_come_back_only_when_asked(open_bus: OpenBus) -> None:
    a, b = open_bus(receive_own_messages=True), open_bus()
    a.send(frame(0x123, b"x"))
    (theirs,) = drain(b, 1)
    (own,) = drain(a, 1)
    assert own.is_rx is False and theirs.is_rx is True and own.timestamp == theirs.timestamp
    assert b.recv(0) is None


def test_filters_apply_to_what_a_bus_returns(open_bus: OpenBus) -> None:
    a = open_bus()
    b = open_bus(can_filters=[{"can_id": 0x180, "can_mask": 0x780}])
    for can_id in (0x181, 0x201, 0x182):
        a.send(frame(can_id))
    assert ids(drain(b, 2)) == [0x181, 0x182]


def _waits_in_the_wire(thread: threading.Thread) -> bool:
    frame = sys._current_frames().get(thread.ident or 0)
    while frame is not None:
        if frame.f_code.co_name == "_wait" and frame.f_code.co_filename.endswith("wire.py"):
            return True
        frame = frame.f_back
    return False


def test_a_reader_blocked_in_recv_is_woken_by_shutdown(open_bus: OpenBus) -> None:
    bus = open_bus(realtime=True)
    result: list[BaseException] = []

    def read() -> None:
        try:
            bus.recv()
        except can.CanOperationError as err:
            result.append(err)

    reader = threading.Thread(target=read)
    reader.start()
    wait_until(lambda: _waits_in_the_wire(reader), what="the reader blocked in recv")
    bus.shutdown()
    reader.join(2.0)
    assert not reader.is_alive() and result


def test_classic_nodes_neither_receive_nor_acknowledge_fd_frames(open_bus: OpenBus) -> None:
    fd_sender, classic = open_bus(fd=True), open_bus()
    fd_sender.send(frame(0x181, bytes(16), is_fd=True, bitrate_switch=True))
    assert classic.recv(0.01) is None  # no FD node acknowledges: the sender retries
    assert fd_sender.node_stats().tec == 128 and fd_sender.state == can.BusState.PASSIVE
    fd_reader = open_bus(fd=True)
    got = fd_reader.recv(1.0)
    assert got is not None and got.is_fd
    # an error-passive node's FD frames carry ESI recessive
    assert got.error_state_indicator
    fd_sender.send(frame(0x182, b"\x01"))  # classic frames reach every node
    assert classic.recv(1.0) is not None and fd_reader.recv(1.0) is not None


def test_bit_timing_objects_give_the_bitrates(open_bus: OpenBus) -> None:
    timing = can.BitTimingFd.from_sample_point(
        f_clock=80_000_000, nom_bitrate=500_000, nom_sample_point=80.0,
        data_bitrate=2_000_000, data_sample_point=80.0)
    bus = open_bus(timing=timing)
    assert (bus.bitrate, bus.data_bitrate, bus.protocol) == (
        500_000, 2_000_000, can.CanProtocol.CAN_FD)


@settings(max_examples=200)
@given(gaps=st.lists(st.tuples(st.floats(0, 2e-4), st.floats(1e-5, 3e-4), st.booleans()),
                     min_size=1, max_size=60),
       now_back=st.floats(-5e-4, 3e-3), window=st.floats(1e-6, 0.02))
def test_the_load_window_counts_what_lies_in_it(gaps: list[tuple[float, float, bool]],
                                                now_back: float, window: float) -> None:
    """Busy time and delivered frames in [now - window, now], against a plain sum."""
    span_s = 0.01
    load = LoadWindow(span_s)
    spans, t = [], 0.0
    for gap, length, ok in gaps:
        start, end = t + gap, t + gap + length
        load.add(start, end, end if ok else None)
        spans.append((start, end, end if ok else None))
        t = end
    now = t - now_back
    low = now - min(window, span_s)
    kept = [s for s in spans if s[1] >= t - span_s]  # what the window still holds
    busy = sum(max(0.0, min(e, now) - max(s, low)) for s, e, _ in kept)
    frames = sum(d is not None and low < d <= now for _, _, d in kept)
    got_busy, got_frames = load.measure(now, window)
    assert got_frames == frames
    assert got_busy == pytest.approx(busy, abs=1e-12)
