"""The timed wire in real time, run by whoever looks at it: readers blocked in recv, senders,
statistics, nodes joining, leaving or changing. Every frame still arrives once, after its
end, stamped exactly, in the order its submission time gives, whoever carried it and when.

Wall-clock lateness is only bounded generously (the machine is shared); orders and stamps
are asserted exactly."""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
import pytest

from canbus.framebits import frame_bits
from canbus.timed import TimedBus
from tests.canbus.timed.stamps import STAMP, check_starts
from tests.support.rigs.waiting import wait_until

OpenBus = Callable[..., TimedBus]
ZEROS_8_BITS = 127  # an 8-byte all-zero frame with id 0 (hand-counted in test_framebits.py)


def frame(can_id: int, data: bytes = b"", **kwargs: Any) -> can.Message:
    kwargs.setdefault("is_extended_id", False)
    return can.Message(arbitration_id=can_id, data=data, **kwargs)


def seconds_of(msg: can.Message, bitrate: int) -> float:
    """The frame's time on the wire, intermission included."""
    return frame_bits(msg.arbitration_id, bytes(msg.data)).total / bitrate


class Reader(threading.Thread):
    """Reads a bus until it has ``n`` frames (or ``seconds`` pass), noting when each came.

    Each ``recv`` may wait ``timeout`` s: a frame that arrives long after its end shows that
    nothing timed it and the reader only looked again when its ``recv`` timed out."""

    def __init__(self, bus: can.BusABC, n: int, seconds: float = 5.0,
                 timeout: float = 0.5) -> None:
        super().__init__(daemon=True)
        self.bus, self.n, self.seconds, self.timeout = bus, n, seconds, timeout
        self.got: list[tuple[can.Message, float]] = []
        self.started_at = threading.Event()

    def run(self) -> None:
        deadline = time.monotonic() + self.seconds
        self.started_at.set()
        while len(self.got) < self.n and time.monotonic() < deadline:
            msg = self.bus.recv(self.timeout)
            if msg is not None:
                self.got.append((msg, time.time()))


def _until(readers: list[Reader], total: int, seconds: float = 30.0) -> None:
    """Wait until the readers have ``total`` frames between them, then stop them."""
    wait_until(lambda: sum(len(r.got) for r in readers) >= total, timeout=seconds,
               what=f"{total} frames read")
    for reader in readers:
        reader.n = 0  # ends after its current recv
    for reader in readers:
        reader.join(5.0)


def _blocked(reader: Reader) -> None:
    reader.start()
    reader.started_at.wait()
    wait_until(lambda: _in_recv(reader), what="the reader blocked in recv")


def _past(bus: TimedBus, wire_time: float) -> None:
    """Let the wire's clock pass ``wire_time`` while nobody looks at the wire (the frames
    that end meanwhile are carried out by whoever looks next, stamped exactly)."""
    while bus.now() <= wire_time:
        time.sleep(0.002)  # pacing: the wire's clock is the machine's, in real time


def _in_recv(reader: threading.Thread) -> bool:
    """The thread waits inside the wire (for a frame, or for room to send one)."""
    frame = sys._current_frames().get(reader.ident or 0)
    while frame is not None:
        code = frame.f_code
        if code.co_name in ("_wait", "_wait_room") and code.co_filename.endswith("wire.py"):
            return True
        frame = frame.f_back
    return False


def _cpu_s(thread: threading.Thread) -> float:
    """CPU seconds a thread has used (its own, whatever else runs on the machine)."""
    fields = Path(f"/proc/self/task/{thread.native_id}/stat").read_text().rsplit(")", 1)[1]
    utime, stime = (int(v) for v in fields.split()[11:13])
    return (utime + stime) / os.sysconf("SC_CLK_TCK")


# ------------------------------------------------------------------------ readers


def test_a_blocked_reader_gets_frames_sent_from_another_thread_after_their_end(
        open_bus: OpenBus) -> None:
    bitrate = 100_000  # 40 frames of 1.27 ms: the last ends 50 ms after the sends
    sender, receiver = open_bus(realtime=True, bitrate=bitrate), open_bus(
        realtime=True, bitrate=bitrate)
    reader = Reader(receiver, 40, seconds=60.0, timeout=60.0)
    _blocked(reader)  # the wire idle: nothing to time
    sent = []
    for _ in range(40):
        before = sender.now()
        sender.send(frame(0, bytes(8)))
        sent.append((before, sender.now()))
    reader.join(60.0)
    got = reader.got
    assert len(got) == 40
    # mostly back to back, 127 bits apart, whatever the wake-ups
    check_starts([m.timestamp for m, _ in got], sent, ZEROS_8_BITS, bitrate)
    assert all(arrived >= msg.timestamp for msg, arrived in got)  # never before its end
    # each came soon after its end (0.5 ms resolution; a loaded machine adds to it), not
    # when the reader's 60 s recv ran out: the reader timed its wait by the wire
    assert max(arrived - msg.timestamp for msg, arrived in got) < 30.0  # any machine: 60 s
    assert not [t for t in threading.enumerate() if t.name.startswith("timed wire")]


def test_whoever_runs_the_wire_hands_a_waiting_reader_its_frame(open_bus: OpenBus) -> None:
    # with wake-ups at least 0.1 s apart, the reader's second wait is timed for 0.1 s after
    # its first frame; a statistics call after the second frame's end delivers it to the
    # reader's node there and then (unless the reader's timer, on a stalled machine, came
    # first), and the reader has it. How soon the reader runs is the scheduler's.
    sender = open_bus(realtime=True, resolution_s=0.1)
    receiver = open_bus(realtime=True)
    reader = Reader(receiver, 2, seconds=60.0, timeout=30.0)
    _blocked(reader)
    sender.send(frame(0, bytes(8)))
    wait_until(lambda: reader.got, what="the first frame")
    wait_until(lambda: _in_recv(reader), what="the reader waiting again")
    sender.send(frame(0, bytes(8)))
    _past(sender, sender.now() + seconds_of(frame(0, bytes(8)), 1_000_000))
    sender.wire_stats()
    delivered = receiver.node_stats().received  # by the statistics call, at the latest
    reader.join(60.0)
    assert delivered == 2
    (first, _), (second, arrived) = reader.got
    assert arrived >= second.timestamp >= first.timestamp  # any machine: an order


def test_every_reader_of_a_channel_gets_every_frame_once(open_bus: OpenBus) -> None:
    a, b, c = (open_bus(realtime=True) for _ in range(3))
    readers = {bus: Reader(bus, 60 if bus is c else 30) for bus in (a, b, c)}
    for reader in readers.values():
        reader.start()
    for k in range(30):  # a and b send, each frame reaching the two others
        a.send(frame(0x100 + k, k.to_bytes(2, "little")))
        b.send(frame(0x300 + k, k.to_bytes(2, "little")))
    for reader in readers.values():
        reader.join(5.0)
    ids = {bus: [m.arbitration_id for m, _ in r.got] for bus, r in readers.items()}
    assert ids[a] == [0x300 + k for k in range(30)]
    assert ids[b] == [0x100 + k for k in range(30)]
    assert sorted(ids[c]) == sorted(ids[a] + ids[b]) and len(ids[c]) == 60
    stamps = [m.timestamp for m, _ in readers[c].got]
    assert stamps == sorted(stamps)
    # the same frame reaches its two receivers with the same stamp, in separate copies
    first_a = next(m for m, _ in readers[c].got if m.arbitration_id == 0x100)
    assert first_a.timestamp == readers[b].got[0][0].timestamp
    assert first_a is not readers[b].got[0][0]


def test_racing_senders_and_readers_lose_and_double_nothing(open_bus: OpenBus) -> None:
    senders = [open_bus(realtime=True) for _ in range(4)]
    listeners = [open_bus(realtime=True) for _ in range(2)]
    readers = [Reader(bus, 400, seconds=10.0, timeout=0.2) for bus in listeners
               for _ in range(2)]  # two threads on each listener
    for reader in readers:
        reader.start()

    def send(k: int) -> None:
        for seq in range(100):
            senders[k].send(frame(0x100 * (k + 1), seq.to_bytes(2, "little")))

    threads = [threading.Thread(target=send, args=(k,)) for k in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(10.0)
    _until(readers, 800)
    for j in range(2):
        got = sorted((m for r in readers[2 * j:2 * j + 2] for m, _ in r.got),
                     key=lambda m: m.timestamp)
        assert len(got) == 400
        stamps = [m.timestamp for m in got]
        assert len(set(stamps)) == 400  # one frame on the wire at a time: 400 distinct ends
        for k in range(4):  # each sender's frames once each, in its FIFO order
            seqs = [int.from_bytes(m.data, "little") for m in got
                    if m.arbitration_id == 0x100 * (k + 1)]
            assert seqs == list(range(100))
    assert all(arrived >= msg.timestamp for r in readers for msg, arrived in r.got)


def test_two_threads_reading_one_bus_share_its_frames(open_bus: OpenBus) -> None:
    sender, shared = open_bus(realtime=True), open_bus(realtime=True)
    first, second = Reader(shared, 100, timeout=0.1), Reader(shared, 100, timeout=0.1)
    first.start()
    second.start()
    for k in range(50):
        sender.send(frame(0x200, k.to_bytes(2, "little")))
    _until([first, second], 50)
    got = sorted(int.from_bytes(m.data, "little") for r in (first, second) for m, _ in r.got)
    assert got == list(range(50))  # each frame once, to one of them


def test_a_reader_that_filters_waits_past_the_frames_it_drops(open_bus: OpenBus) -> None:
    sender = open_bus(realtime=True)
    picky = open_bus(realtime=True, can_filters=[{"can_id": 0x7FF, "can_mask": 0x7FF}])
    for k in range(20):
        sender.send(frame(0x100 + k))
    sender.send(frame(0x7FF, b"\x01"))
    msg = picky.recv(2.0)
    assert msg is not None and msg.arbitration_id == 0x7FF
    assert picky.recv(0.01) is None


def test_recv_returns_at_its_timeout_while_the_wire_carries_what_it_drops(
        open_bus: OpenBus) -> None:
    # 3,000 frames of 12.7 ms keep the wire busy for 38 s, each one delivered to the
    # reader and dropped by its filter: its recv still ends at its own timeout
    sender = open_bus(realtime=True, bitrate=10_000, tx_queue_size=3000)
    picky = open_bus(realtime=True, bitrate=10_000,
                     can_filters=[{"can_id": 0x7FF, "can_mask": 0x7FF}])
    for _ in range(3000):
        sender.send(frame(0, bytes(8)))
    started = time.monotonic()
    assert picky.recv(0.05) is None
    took = time.monotonic() - started
    assert 0.05 <= took < 19.0  # any machine: a wait never ends early; the wire, 38 s
    started = time.monotonic()
    assert picky.recv(0) is None
    assert time.monotonic() - started < 19.0  # any machine: as above
    assert picky.node_stats().received > 0  # the frames did reach it


def test_shutdown_ends_a_blocked_reader_and_a_blocked_sender(open_bus: OpenBus) -> None:
    # the sender is alone: its frame is never acknowledged, its queue of one stays full
    sender, reader_bus = open_bus(realtime=True, tx_queue_size=1), open_bus(
        realtime=True, channel="timed-test-shutdown-other")
    sender.send(frame(0x100))
    errors: list[BaseException] = []

    def call(what: Callable[[], object]) -> None:
        try:
            what()
        except can.CanOperationError as err:
            errors.append(err)

    threads = [threading.Thread(target=call, args=(lambda: sender.send(frame(0x101)),)),
               threading.Thread(target=call, args=(reader_bus.recv,))]
    for thread in threads:
        thread.start()
    wait_until(lambda: all(_in_recv(t) for t in threads),  # type: ignore[arg-type]
               what="both blocked in the wire")  # (no timeout)
    sender.shutdown()
    reader_bus.shutdown()
    for thread in threads:
        thread.join(2.0)
    assert not any(thread.is_alive() for thread in threads) and len(errors) == 2


def test_waiting_readers_cost_no_cpu(open_bus: OpenBus) -> None:
    # one reader on an idle wire; another while a sender alone retries forever, error
    # passive, its retries counted as time passes rather than carried one by one
    idle = open_bus(realtime=True, channel="timed-test-idle-wire")
    alone, deaf = open_bus(realtime=True), open_bus(realtime=True, acknowledge=False,
                                                    receive_error_frames=True)
    alone.send(frame(0x321))
    readers = [Reader(idle, 1, seconds=0.6, timeout=0.6),
               Reader(deaf, 10**6, seconds=0.6, timeout=0.6)]
    for reader in readers:
        reader.start()
    wait_until(lambda: all(_in_recv(r) for r in readers), what="the readers waiting")
    cpu = [_cpu_s(r) for r in readers]
    time.sleep(0.4)  # pacing: a span of waiting
    used = [_cpu_s(r) - c for r, c in zip(readers, cpu, strict=True)]
    # the readers' own CPU, which other work on the machine does not add to; a busy loop
    # would take its core's share
    assert max(used) < 0.05, used  # any machine: CPU time, not wall time
    for reader in readers:
        reader.join(2.0)
    assert alone.wire_stats().error_frames > 1000


# ------------------------------------------------------------- nobody reading


def test_frames_go_out_on_time_while_nobody_reads(open_bus: OpenBus) -> None:
    sender = open_bus(realtime=True)
    silent = open_bus(realtime=True)  # acknowledges, never reads until the end
    sent = []
    for _ in range(10):
        before = sender.now()
        sender.send(frame(0, bytes(8)))
        sent.append((before, sender.now()))
    _past(sender, sent[-1][1] + 2 * ZEROS_8_BITS / 1_000_000)
    stats = silent.wire_stats()  # statistics carry out what fell due
    assert stats.frames == 10 and silent.node_stats().received == 10
    stamps = [m.timestamp for m in (silent.recv(0) for _ in range(10)) if m]
    check_starts(stamps, sent, ZEROS_8_BITS, 1_000_000)


def test_frames_carried_late_keep_the_order_their_submission_times_give(
        open_bus: OpenBus) -> None:
    bitrate = 10_000  # an 8-byte zero frame holds the wire 12.7 ms
    slow = {"realtime": True, "bitrate": bitrate}
    a, b, c, listener = (open_bus(**slow) for _ in range(4))
    first, second, third = frame(0x300, bytes(8)), frame(0x200), frame(0x100)
    a.send(first)
    _past(a, a.now() + seconds_of(first, bitrate))  # the first frame ended; the wire is idle
    before = b.now()
    b.send(second)  # starts at once: it is alone when it is sent
    after, sent = b.now(), time.monotonic()
    c.send(third)  # smaller id, but the wire was taken
    gap = time.monotonic() - sent
    _past(c, c.now() + 2 * seconds_of(second, bitrate))  # all three ended; nobody reads
    got = [listener.recv(0) for _ in range(3)]
    assert [m.arbitration_id for m in got if m] == [0x300, 0x200, 0x100]
    one, two, three = (m.timestamp for m in got if m)
    start = two - seconds_of(second, bitrate) + 3 / bitrate  # its end is before the IFS
    assert before - STAMP <= start <= after + STAMP and start > one  # any machine: wire's clock
    if gap < seconds_of(second, bitrate) / 2:  # the third was queued while the second ran
        assert three - two == pytest.approx(seconds_of(third, bitrate), abs=STAMP)
    else:
        assert three - two >= seconds_of(third, bitrate) - STAMP


def test_a_listener_that_joins_later_gets_only_what_ends_after(open_bus: OpenBus) -> None:
    sender, other = open_bus(realtime=True), open_bus(realtime=True)
    for k in range(5):
        sender.send(frame(0x100 + k))
    _past(sender, sender.now() + 5 * seconds_of(frame(0x100), 1_000_000))  # nobody looked
    late = open_bus(realtime=True)
    sender.send(frame(0x200))
    assert [m.arbitration_id for m in (late.recv(1.0), late.recv(0.01)) if m] == [0x200]
    assert [m.arbitration_id for m in (other.recv(0) for _ in range(6)) if m] == [
        0x100, 0x101, 0x102, 0x103, 0x104, 0x200]


def test_frames_that_ended_keep_their_acknowledgement(open_bus: OpenBus) -> None:
    sender, only = open_bus(realtime=True), open_bus(realtime=True)
    for k in range(5):
        sender.send(frame(0x100 + k))
    _past(sender, sender.now() + 5 * seconds_of(frame(0x100), 1_000_000))  # acknowledged
    only.acknowledge = False  # from now on: frames that ended stay acknowledged
    stats = only.wire_stats()
    assert (stats.frames, stats.error_frames) == (5, 0)
    assert len([m for m in (only.recv(0) for _ in range(5)) if m]) == 5


def test_a_sender_that_closes_leaves_its_ended_frames_delivered(open_bus: OpenBus) -> None:
    sender, listener = open_bus(realtime=True), open_bus(realtime=True)
    for k in range(5):
        sender.send(frame(0x100 + k))
    _past(sender, sender.now() + 5 * seconds_of(frame(0x100), 1_000_000))
    sender.shutdown()
    assert [m.arbitration_id for m in (listener.recv(0) for _ in range(5)) if m] == [
        0x100, 0x101, 0x102, 0x103, 0x104]


def test_a_sender_waiting_for_room_runs_the_wire_itself(open_bus: OpenBus) -> None:
    slow = {"realtime": True, "bitrate": 10_000}  # an 8-byte zero frame holds it 12.7 ms
    sender = open_bus(tx_queue_size=1, **slow)
    silent = open_bus(**slow)  # acknowledges; nobody ever calls recv
    started = time.monotonic()
    for _ in range(4):  # each send waits for the frame before it to leave the queue
        sender.send(frame(0, bytes(8)), timeout=30.0)
    assert time.monotonic() - started >= 2 * 0.0127  # any machine: a lower bound
    _past(sender, sender.now() + 2 * 0.0127)
    assert silent.wire_stats().frames == 4


def test_a_blocked_sender_goes_on_when_a_node_that_acknowledges_joins(
        open_bus: OpenBus) -> None:
    # alone, its frame is retried forever and its queue of one stays full; a node that
    # joins (and never reads) acknowledges the retry: the queue empties, the send returns
    sender = open_bus(realtime=True, tx_queue_size=1)
    sender.send(frame(0x100))
    done = threading.Event()

    def send() -> None:
        sender.send(frame(0x101), timeout=5.0)
        done.set()

    thread = threading.Thread(target=send, daemon=True)
    thread.start()
    wait_until(lambda: _in_recv(thread), what="the sender waiting for room")  # type: ignore[arg-type]
    assert not done.is_set()
    joined = open_bus(realtime=True)
    assert done.wait(30.0)
    thread.join(1.0)
    assert [m.arbitration_id for m in (joined.recv(0.5), joined.recv(0.5)) if m] == [
        0x100, 0x101]


def test_a_full_receive_queue_loses_frames_in_real_time(open_bus: OpenBus) -> None:
    sender = open_bus(realtime=True)
    small = open_bus(realtime=True, rx_queue_size=3)
    reader = Reader(open_bus(realtime=True), 10)
    reader.start()
    for k in range(10):
        sender.send(frame(0x180 + k))
    reader.join(5.0)
    assert len(reader.got) == 10
    stats = small.node_stats()
    assert (stats.received, stats.lost_overflow) == (3, 7)
    assert [m.arbitration_id for m in (small.recv(0) for _ in range(3)) if m] == [
        0x180, 0x181, 0x182]


def test_bus_off_and_recovery_in_real_time(open_bus: OpenBus) -> None:
    # every attempt hit by a bit error until the sender is bus off; then no more errors:
    # after 128 x 11 recessive bits it is back and its frame, kept queued, goes out
    bitrate = 10_000  # an attempt takes a few ms, the recovery 141 ms: time to look
    sender = open_bus(realtime=True, bitrate=bitrate, error_probability=1.0, error_seed=3)
    listener = open_bus(realtime=True, bitrate=bitrate, receive_error_frames=True)
    reader = Reader(listener, 10**6, seconds=10.0, timeout=0.2)
    _blocked(reader)
    sent = frame(0x100, b"\x01")
    sender.send(sent)
    wait_until(lambda: sender.node_stats().state == can.BusState.ERROR, interval=0.001,
               what="the sender bus off")
    assert sender.state == can.BusState.ERROR
    sender.error_probability = 0.0
    wait_until(lambda: any(not m.is_error_frame for m, _ in reader.got),
               what="the frame after the recovery")
    _until([reader], 0)
    errors = [m for m, _ in reader.got if m.is_error_frame]
    (data,) = [m for m, _ in reader.got if not m.is_error_frame]
    # TEC 256 after 32 errors (64 if this thread looked too late, after a recovery)
    bus_offs = len(errors) // 32
    assert len(errors) == 32 * bus_offs and bus_offs >= 1 and reader.got[-1][0] is data
    assert data.data == b"\x01" and sender.state == can.BusState.ACTIVE
    assert [b.timestamp for b in errors] == sorted(b.timestamp for b in errors)
    # the frame starts right after the recovery: the last error frame's intermission, then
    # 128 x 11 idle bits; its stamp is its end
    gap = (128 * 11 + frame_bits(0x100, b"\x01").total) / bitrate
    assert data.timestamp - errors[-1].timestamp == pytest.approx(gap, abs=STAMP)
    stats = sender.node_stats()
    assert (stats.sent, stats.errors, stats.bus_off_count, stats.tec) == (
        1, len(errors), bus_offs, 0)
