"""The shared wire of a timed channel: arbitration, exact frame times, delivery.

Every bus opened on a channel in this process is a node on that channel's :class:`Wire`. A
node's frames leave in the order it sent them (a FIFO transmit queue, the default of most
controllers). When the wire falls idle, the head frames of all nodes arbitrate and the one
with the smallest arbitration field (``canbus.framebits.arbitration_key``) goes next; two
frames with the same field (a design error on a real bus, where both would collide) go in
the order they were sent, then by node.

Timing, all on the wire's clock: a frame submitted at time ``s`` starts at ``max(s, end of
the previous frame)``; it occupies the wire for its exact bits (``canbus.framebits``), its
receivers get it at the end of its EOF, stamped with that time, and the next frame starts
after the 3-bit intermission. The arbitration at the end of a frame is among the frames
submitted before its EOF ended (a frame submitted during the 3 intermission bits waits for
the next arbitration unless the wire has nothing else to send): so the order and the
timestamps depend only on when frames were submitted, never on when the wire is run.

Real time (the default): the clock is ``time.time()``, and whoever waits for the wire runs
it: a reader blocked in ``recv`` sleeps until the end of the next frame that may reach it
(wake-ups at least ``resolution_s`` apart), then carries out every event whose time has
passed (delivering each frame, stamped with its own end, to every receiver, and waking the
readers it reached) and sleeps again. Every other call (send, statistics, a node joining,
leaving or changing, a sender waiting for room) first carries out what fell due, so a frame
that ended before a node joined never reaches it, one that ended before a node stopped
acknowledging stays acknowledged, and a process that only sends, or whose readers come
later, still gets every frame at its own time. No thread of its own: a reader is woken once
for the frames it gets, not once by a wire thread and again by the hand-over (each wake-up
of a thread costs more CPU than carrying a frame).

Simulated time (``realtime=False``): the clock starts at ``time.time()`` and moves only as
frames cross the wire (or by :meth:`Wire.advance`); a ``recv`` runs the wire until its node
has a frame, frames submitted meanwhile are stamped with the simulated time.
"""
from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable, Hashable
from dataclasses import dataclass

import can

from canbus.framebits import F_ESI, F_FD, IFS_BITS, FrameBits, bits_unchecked
from canbus.timed import message
from canbus.timed.errors import TimedBusError
from canbus.timed.faults import (
    ERROR_FRAME_BITS,
    PASSIVE_ABOVE,
    RECOVERY_RUN_BITS,
    RECOVERY_SEQUENCES,
    SUSPEND_BITS,
    BitErrors,
    ack_error_time_s,
)
from canbus.timed.node import Node, Pending, Waiter, waiter
from canbus.timed.stats import LoadWindow, NodeStats, WireStats

OK, BIT_ERROR, ACK_ERROR = 0, 1, 2

@dataclass(slots=True)
class _Flight:
    """A frame (or failed attempt) on the wire."""

    node: Node
    pending: Pending
    start: float
    done: float
    """End of EOF (delivery, timestamp) or of the error delimiter."""
    end: float
    """``done`` + intermission: the wire is free."""
    bits: FrameBits
    flags: int
    outcome: int


@dataclass(slots=True)
class _Stuck:
    """An error-passive node retrying a frame nobody acknowledges, nothing else to send.

    Nothing can change until something happens from outside (a frame submitted, a node
    joining, leaving or acknowledging again), so the attempts are not played one by one:
    they are counted when that happens, attempt ``k`` starting at ``first + k * period``.
    """

    node: Node
    pending: Pending
    first: float
    period: float
    length: float
    done: float
    bits: FrameBits
    flags: int


def _attempts(stuck: _Stuck | None, now: float) -> int:
    """Attempts of a stuck retry loop begun by ``now``."""
    if stuck is None or now < stuck.first:
        return 0
    return int((now - stuck.first) // stuck.period) + 1


class Wire:
    """One channel's medium; use it through ``TimedBus``."""

    def __init__(self, channel: Hashable, bitrate: int, data_bitrate: int | None,
                 realtime: bool, window_s: float, resolution_s: float = 0.0) -> None:
        self.channel = channel
        self.bitrate = bitrate
        self.data_bitrate = data_bitrate
        self.realtime = realtime
        self.bit_s = 1.0 / bitrate
        self.ifs_s = IFS_BITS / bitrate
        self.lock = threading.Lock()
        self.wake = threading.Condition(self.lock)
        """Simulated time: readers waiting for another thread to send."""
        self.nodes: list[Node] = []
        self._next_index = 0
        self.started = time.time()
        # Times inside are seconds since ``started``: small numbers keep bit-time precision
        # (an absolute time.time() float resolves only 0.24 us and would drift frame by frame).
        self.sim_now = 0.0
        self.free_at = 0.0
        self.flight: _Flight | None = None
        self.stuck: _Stuck | None = None
        self.window = LoadWindow(window_s)
        self.frames = self.nominal_bits = self.data_bits = 0
        self.error_frames = self.retransmissions = 0
        self.busy_s = 0.0
        self.off = 0
        """Nodes that are bus off (their recovery is counted only while there are some)."""
        self.resolution_s = resolution_s
        self.batch_at = -math.inf
        """Real time: when a woken reader last ran the wire (the next timed wake-up is at
        least ``resolution_s`` later)."""

    @property
    def data_bit_s(self) -> float:
        return 1.0 / self.data_bitrate if self.data_bitrate else self.bit_s

    # ---------------------------------------------------------------- membership

    def add_node(self, *, name: str | None, fd: bool, receive_own: bool,
                 receive_error_frames: bool, acknowledge: bool, tx_limit: int, rx_limit: int,
                 errors: BitErrors) -> Node:
        """A new node (``canbus.timed.channels.join`` calls it under the registry lock)."""
        with self.lock:
            node = Node(index=self._next_index, name=name or f"node{self._next_index}", fd=fd,
                        receive_own=receive_own, receive_error_frames=receive_error_frames,
                        acknowledge=acknowledge, tx_limit=tx_limit, rx_limit=rx_limit,
                        errors=errors, room=threading.Condition(self.lock))
            self._next_index += 1
            self._event()
            self.nodes.append(node)
            self._signal()
        return node

    def remove_node(self, node: Node) -> bool:
        """The node leaves; its queued frames go (one on the wire finishes). True if it was
        the last: the wire is then closed."""
        with self.lock:
            if not node.open:
                return False
            self._event()
            self.off -= node.bus_off
            node.open = False
            node.tx.clear()
            self.nodes.remove(node)
            self._rouse(node)  # a reader blocked in recv returns (its bus says it is closed)
            node.room.notify_all()
            self._signal()
            return not self.nodes

    def update(self, node: Node, *, acknowledge: bool | None = None,
               error_probability: float | None = None) -> None:
        """Change how a node behaves from now on."""
        with self.lock:
            self._event()
            if acknowledge is not None:
                node.acknowledge = acknowledge
            if error_probability is not None:
                node.errors.probability = error_probability
            self._signal()

    # ---------------------------------------------------------------- traffic

    def submit(self, node: Node, pending: Pending, timeout: float | None) -> None:
        with self.lock:
            if not node.open:
                raise TimedBusError("Cannot operate on a closed bus")
            if len(node.tx) >= node.tx_limit:
                self._wait_room(node, timeout)
            now = self._event()
            pending.submitted = now
            node.tx.append(pending)
            if not self.realtime:
                self.wake.notify_all()
                return
            # Readers it may reach and that wait for nothing in particular must start timing
            # it; on an idle wire it may also end before what timed readers wait for.
            idle = self.flight is None
            for other in self.nodes:
                if other.waiters and (other is not node or other.receive_own
                                      or other.receive_error_frames):
                    self._rouse(other, timed=idle)

    def _wait_room(self, node: Node, timeout: float | None) -> None:
        """Wait for room in the node's transmit queue: running the wire meanwhile."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while len(node.tx) >= node.tx_limit:
            if self.realtime:
                now = time.time() - self.started
                next_at = self._process(now)
                wake_in = None if next_at is None else next_at - now
            else:
                self._process(math.inf, lambda: len(node.tx) < node.tx_limit)
                wake_in = None
            if len(node.tx) < node.tx_limit:
                break
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                raise TimedBusError(f"transmit queue full ({node.tx_limit} frames) for "
                                    f"{timeout} s on timed channel {self.channel}")
            if wake_in is not None:
                remaining = wake_in if remaining is None else min(remaining, wake_in)
            node.room_waiters += 1
            try:
                node.room.wait(remaining)
            finally:
                node.room_waiters -= 1
            if not node.open:
                raise TimedBusError("Cannot operate on a closed bus")

    def receive(self, node: Node, timeout: float | None,
                accept: Callable[[can.Message], bool] | None = None) -> can.Message | None:
        """The node's next frame ``accept`` takes (others are dropped, as filters do), waiting
        up to ``timeout`` seconds (None: no limit); None also once the node is closed.

        Real time: while none is there the caller runs the wire (:meth:`_receive_realtime`).
        Simulated time: the wire runs until the node has a frame or ``timeout`` of simulated
        time has passed; if nothing is left to simulate it waits, in real time, for another
        thread to send.
        """
        if self.realtime:
            return self._receive_realtime(node, timeout, accept)
        deadline = None if timeout is None else time.monotonic() + timeout
        rx = node.rx
        with self.lock:
            horizon = math.inf if timeout is None else self.sim_now + timeout
            while True:
                msg = _first_accepted(rx, accept)
                if msg is not None:
                    return msg
                if not node.open:
                    return None
                self._process(horizon, lambda: bool(rx))
                pending = self._next_time() is not None
                if rx:
                    if pending:
                        self.wake.notify_all()  # other readers may be waiting for these
                    continue
                if pending or (self.stuck is not None and horizon < math.inf):
                    self.sim_now = max(self.sim_now, horizon)  # the simulated timeout ran out
                    return None
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return None
                self.wake.wait(remaining)  # until another thread submits

    def _receive_realtime(self, node: Node, timeout: float | None,
                          accept: Callable[[can.Message], bool] | None) -> can.Message | None:
        """Real time: carry out what fell due; while nothing is there for the node, sleep to
        the next event that may bring something (or until woken) and look again."""
        deadline = None if timeout is None else time.monotonic() + timeout
        rx = node.rx
        with self.lock:
            while True:
                msg = _first_accepted(rx, accept)
                if msg is not None:
                    return msg
                if not node.open:
                    return None
                now = time.time() - self.started
                next_at = self._process(now)
                if rx:
                    continue
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return None
                timed = next_at is not None and self._may_reach(node)
                if timed:
                    assert next_at is not None
                    wake_in = max(next_at, self.batch_at + self.resolution_s) - now
                    if remaining is None or wake_in < remaining:
                        remaining = wake_in
                self._wait(node, remaining, timed)
                if timed:  # a frame after an idle spell is still delivered at its end
                    self.batch_at = time.time() - self.started

    def _may_reach(self, node: Node) -> bool:
        """Whether something on the wire or queued may still reach the node (else only a new
        frame can, and its ``submit`` wakes the node's reader)."""
        own = node.receive_own or node.receive_error_frames
        flight = self.flight
        if flight is not None and (flight.node is not node or own):
            return True
        return any(other.tx and (other is not node or own) for other in self.nodes)

    def _wait(self, node: Node, timeout: float | None, timed: bool) -> None:
        """Sleep up to ``timeout`` s (None: no limit) or until :meth:`_rouse`. Lock held on
        entry and on exit (released meanwhile).

        A bare lock per thread rather than a Condition: a Condition's wait allocates a lock
        and a list entry each time, which doubled the CPU of a wake-up.
        """
        me = waiter()
        me.timed, me.roused = timed, False
        node.waiters.append(me)
        self.lock.release()
        woken = False
        try:
            woken = me.alarm.acquire(True, -1 if timeout is None else max(timeout, 0.0))
        finally:
            self.lock.acquire()
            if not me.roused:
                node.waiters.remove(me)
            elif not woken:
                me.alarm.acquire()  # roused just as it timed out: take the permit back

    @staticmethod
    def _rouse(node: Node, *, timed: bool = True) -> None:
        """Wake the node's waiting readers (with ``timed`` False only those that wait for
        nothing in particular). Lock held."""
        kept: list[Waiter] = []
        for sleeper in node.waiters:
            if sleeper.timed and not timed:
                kept.append(sleeper)
            else:
                sleeper.roused = True
                sleeper.alarm.release()
        node.waiters = kept

    def advance(self, seconds: float) -> None:
        """Simulated time only: let ``seconds`` pass, carrying every frame due meanwhile."""
        if self.realtime:
            raise TimedBusError("advance() is for a simulated-time channel (realtime=False)")
        if seconds < 0:
            raise ValueError(f"cannot advance by {seconds} s")
        with self.lock:
            target = self.sim_now + seconds
            self._process(target)
            self.sim_now = max(self.sim_now, target)
            self.wake.notify_all()

    def flush(self, node: Node) -> None:
        """Drop the node's queued frames (not the one on the wire)."""
        with self.lock:
            self._event()
            on_wire = self.flight.pending if self.flight and self.flight.node is node else None
            node.tx.clear()
            if on_wire is not None:
                node.tx.append(on_wire)
            node.room.notify_all()

    def now(self) -> float:
        """The wire's clock: ``time.time()`` in real time, else the simulated time."""
        return self.started + self._clock()

    def _clock(self) -> float:
        return time.time() - self.started if self.realtime else self.sim_now

    # ---------------------------------------------------------------- the engine

    def _event(self) -> float:
        """Something outside the wire happens now: in real time, first carry out everything
        that fell due (a node joining, leaving or changing must not touch a frame that ended
        before, even if nobody ran the wire since); then settle a stuck retry loop, which
        the event may end. Lock held."""
        if not self.realtime:
            if self.stuck is not None:
                self._unstick(self.sim_now)
                self._signal()
            return self.sim_now
        now = time.time() - self.started
        unstuck = False
        while True:
            self._process(now)
            if self.stuck is None:
                break
            self._unstick(now)  # its last attempt (begun by now) goes on; the wire runs on
            unstuck = True
        if unstuck:
            self._signal()
        return now

    def _signal(self) -> None:
        """Let everyone who waits on the wire look again (the nodes or the queues changed)."""
        if self.realtime:
            for node in self.nodes:
                self._rouse(node)
        else:
            self.wake.notify_all()
        for node in self.nodes:
            if node.room_waiters:
                node.room.notify_all()

    def _process(self, until: float, stop: Callable[[], bool] | None = None) -> float | None:
        """Carry out every event up to ``until`` (or until ``stop()``). Lock held.

        Returns when the next event falls due: None if the wire waits for the outside (or
        ``stop()`` ended the run: then see :meth:`_next_time`).
        """
        while True:
            flight = self.flight
            if flight is not None:
                if flight.done > until:
                    return flight.done
                self._land(flight)
                if stop is not None and stop():
                    return None
                continue
            if self.stuck is not None:
                return None
            recovery, node = self._next_recovery() if self.off else (math.inf, None)
            decision = self._arbitration()
            if decision is not None and decision[0] < recovery:
                cutoff, start, winner, pending = decision
                if cutoff > until:
                    return cutoff
                if not self.realtime and cutoff > self.sim_now:
                    self.sim_now = cutoff
                self._launch(start, winner, pending)
                continue
            if node is None:
                return None
            if recovery > until:
                return recovery
            self._tick(recovery)
            self._recover(node, recovery)

    def _next_time(self) -> float | None:
        """When the next event falls due; None if the wire waits for the outside."""
        if self.flight is not None:
            return self.flight.done
        if self.stuck is not None:
            return None
        recovery = self._next_recovery()[0] if self.off else math.inf
        decision = self._arbitration()
        first = min(recovery, decision[0] if decision is not None else math.inf)
        return None if first == math.inf else first

    def _tick(self, at: float) -> None:
        if not self.realtime and at > self.sim_now:
            self.sim_now = at

    def _arbitration(self) -> tuple[float, float, Node, Pending] | None:
        """(decision time, start, winner, its frame) of the next arbitration, if any."""
        earliest = math.inf
        for node in self.nodes:
            if node.tx and not node.bus_off:
                ready = node.tx[0].submitted
                if node.not_before > ready:
                    ready = node.not_before
                if ready < earliest:
                    earliest = ready
        if earliest == math.inf:
            return None
        free = self.free_at
        cutoff = free - self.ifs_s
        if earliest > cutoff:
            cutoff = earliest
        best: Pending | None = None
        winner: Node | None = None
        for node in self.nodes:
            if node.tx and not node.bus_off:
                pending = node.tx[0]
                if pending.submitted <= cutoff and node.not_before <= cutoff and (
                        best is None or pending.key < best.key or (
                            pending.key == best.key and pending.submitted < best.submitted)):
                    best, winner = pending, node  # nodes in index order: ties go to the first
        assert winner is not None and best is not None
        return cutoff, free if free > earliest else earliest, winner, best

    def _next_recovery(self) -> tuple[float, Node | None]:
        """When the first bus-off node recovers if the wire stays idle."""
        best, first = math.inf, None
        run_s = RECOVERY_RUN_BITS * self.bit_s
        for node in self.nodes:
            if node.bus_off:
                at = max(node.counted_until, self.free_at) + (
                    RECOVERY_SEQUENCES - node.recovery) * run_s
                if at < best:
                    best, first = at, node
        return best, first

    def _recover(self, node: Node, at: float) -> None:
        node.recover(at)
        self.off -= 1

    def _launch(self, start: float, node: Node, pending: Pending) -> None:
        if self.off:
            run_s = RECOVERY_RUN_BITS * self.bit_s
            for other in self.nodes:  # idle time before this frame counts towards recovery
                if other.bus_off and start > other.counted_until:
                    idle = start - max(other.counted_until, self.free_at)
                    other.recovery += int(idle / run_s)
                    other.counted_until = start
                    if other.recovery >= RECOVERY_SEQUENCES:
                        self._recover(other, start)
        flags = pending.flags
        if flags & F_FD and (node.tec > PASSIVE_ABOVE or node.rec > PASSIVE_ABOVE):
            flags |= F_ESI  # an error-passive node's FD frames carry ESI recessive
        bits = pending.bits
        if bits is None or flags != pending.flags:
            bits = bits_unchecked(pending.can_id, flags, pending.dlc, pending.data)
            if flags == pending.flags:
                pending.bits = bits  # for its retransmissions
        if pending.attempts:
            self.retransmissions += 1
        fd = flags & F_FD
        acked = False
        for other in self.nodes:
            if (other.acknowledge and other is not node and other.open and not other.bus_off
                    and (other.fd or not fd)):
                acked = True
                break
        errors = node.errors
        if errors.probability > 0.0 and errors.hit():
            outcome = BIT_ERROR
            held = errors.error_time_s(bits, self.bit_s, self.data_bit_s) + (
                ERROR_FRAME_BITS * self.bit_s)
        elif not acked:
            outcome = ACK_ERROR
            held = ack_error_time_s(bits, self.bit_s, self.data_bit_s) + (
                ERROR_FRAME_BITS * self.bit_s)
        else:
            outcome = OK
            nominal, data = bits[0], bits[1]
            held = (nominal / self.bitrate if not data else
                    bits.duration_s(self.bitrate, self.data_bitrate)) - self.ifs_s
        self.flight = _Flight(node, pending, start, start + held, start + held + self.ifs_s,
                              bits, flags, outcome)

    def _land(self, flight: _Flight) -> None:
        self.flight = None
        node, pending = flight.node, flight.pending
        end = self.free_at = flight.end
        self.busy_s += end - flight.start
        ok = flight.outcome == OK
        self.window.add(flight.start, end, flight.done if ok else None)
        if not self.realtime and flight.done > self.sim_now:
            self.sim_now = flight.done
        if self.off:
            for other in self.nodes:  # every frame and error frame ends with 11 recessive bits
                if other.bus_off and other is not node:
                    other.recovery += 1
                    other.counted_until = end
                    if other.recovery >= RECOVERY_SEQUENCES:
                        self._recover(other, end)
        if ok:
            tx = node.tx
            if tx and tx[0] is pending:
                tx.popleft()
                if node.room_waiters:
                    node.room.notify_all()
            node.sent += 1
            if node.tec:
                node.tec -= 1
            self.frames += 1
            bits = flight.bits
            self.nominal_bits += bits[0]
            self.data_bits += bits[1]
            self._deliver(node, pending.template, flight)
        else:
            self._failed(flight)
        if node.tec > PASSIVE_ABOVE or node.rec > PASSIVE_ABOVE:
            if not node.bus_off:
                node.not_before = end + SUSPEND_BITS * self.bit_s
            if flight.outcome == ACK_ERROR:
                self._maybe_stuck(flight)

    def _failed(self, flight: _Flight) -> None:
        """An attempt that ended in an error frame: counters, error frames to who wants them."""
        node = flight.node
        flight.pending.attempts += 1
        self.error_frames += 1
        node.transmit_error(ack_error=flight.outcome == ACK_ERROR, at=flight.end)
        self.off += node.bus_off and node.open  # a node gone since counts no more
        fd = bool(flight.flags & F_FD)
        for other in self.nodes:
            if other is not node and other.understands(fd):
                if flight.outcome == BIT_ERROR:
                    other.receive_error()
                if other.receive_error_frames:
                    self._put(other, message.error_frame(self.channel,
                                                         self.started + flight.done))
        if node.receive_error_frames and node.open:
            self._put(node, message.error_frame(self.channel, self.started + flight.done))

    def _put(self, node: Node, msg: can.Message) -> None:
        node.rx.append(msg)
        if node.waiters:
            self._rouse(node)

    def _deliver(self, sender: Node, template: can.Message, flight: _Flight) -> None:
        fd = flight.flags & F_FD
        if flight.flags & F_ESI:
            template.error_state_indicator = True
        stamp = self.started + flight.done
        takers = []
        for node in self.nodes:
            if node.bus_off or (fd and not node.fd):
                continue
            if node is sender:
                if not node.receive_own:
                    continue
            elif node.rec:
                node.rec = PASSIVE_ABOVE if node.rec > PASSIVE_ABOVE else node.rec - 1
            if node.rx_limit and len(node.rx) >= node.rx_limit:
                node.lost_overflow += 1
            else:
                takers.append(node)
        if not takers:
            return
        last = takers.pop()  # copies for all but the last taker, which gets the template
        for node in takers:
            node.rx.append(message.delivered(template, stamp, node is not sender))
            node.received += 1
            if node.waiters:
                self._rouse(node)
        template.timestamp, template.is_rx = stamp, last is not sender
        last.rx.append(template)
        last.received += 1
        if last.waiters:
            self._rouse(last)

    def _maybe_stuck(self, flight: _Flight) -> None:
        """After an ACK error: enter the retry loop if nothing but outside events can end it."""
        node, pending = flight.node, flight.pending
        if not (node.open and node.passive and not node.bus_off and node.tx
                and node.tx[0] is pending and node.errors.probability == 0.0):
            return
        fd = bool(flight.flags & F_FD)
        for other in self.nodes:
            if other.bus_off:
                return  # its recovery is an event of the wire's own
            if other is not node and (other.tx or (other.acknowledge and other.understands(fd))):
                return
        length = flight.end - flight.start
        self.stuck = _Stuck(node, pending, node.not_before, length + SUSPEND_BITS * self.bit_s,
                            length, flight.done - flight.start, flight.bits, flight.flags)

    def _unstick(self, now: float) -> None:
        """Count the retry loop's attempts begun by ``now``; the last one goes on the wire."""
        stuck, self.stuck = self.stuck, None
        attempts = _attempts(stuck, now)
        if stuck is None or attempts == 0:
            return
        node, pending = stuck.node, stuck.pending
        done = attempts - 1
        self.error_frames += done
        self.retransmissions += done
        self.busy_s += done * stuck.length
        node.tx_errors += done
        pending.attempts += done
        shown = min(done, int(self.window.span_s / stuck.period) + 1)
        for k in range(done - shown, done):
            start = stuck.first + k * stuck.period
            self.window.add(start, start + stuck.length, None)
        start = stuck.first + done * stuck.period
        self.retransmissions += 1
        self.flight = _Flight(node, pending, start, start + stuck.done, start + stuck.length,
                              stuck.bits, stuck.flags, ACK_ERROR)

    # ---------------------------------------------------------------- statistics

    def node_stats(self, node: Node) -> NodeStats:
        with self.lock:
            if self.realtime:
                self._process(self._clock())
            return node.snapshot()

    def stats(self, window_s: float | None) -> WireStats:
        with self.lock:
            now = self._clock()
            if self.realtime:
                self._process(now)
            extra = _attempts(self.stuck, now)
            length = self.stuck.length if self.stuck is not None else 0.0
            ahead = max(0.0, self.free_at - now)  # the last intermission may not be over
            busy, frames = self.window.measure(now, window_s or self.window.span_s)
            return WireStats(
                channel=str(self.channel), bitrate=self.bitrate, data_bitrate=self.data_bitrate,
                realtime=self.realtime, started=self.started, elapsed_s=now,
                frames=self.frames,
                nominal_bits=self.nominal_bits, data_bits=self.data_bits,
                error_frames=self.error_frames + extra,
                retransmissions=self.retransmissions + extra,
                busy_s=self.busy_s + extra * length - ahead,
                window_s=window_s or self.window.span_s, window_frames=frames,
                window_busy_s=busy, nodes=tuple(n.snapshot() for n in self.nodes))


def _first_accepted(rx: deque[can.Message],
                    accept: Callable[[can.Message], bool] | None) -> can.Message | None:
    """The first received frame ``accept`` takes (those before it are dropped), or None."""
    while rx:
        msg = rx.popleft()
        if accept is None or accept(msg):
            return msg
    return None
