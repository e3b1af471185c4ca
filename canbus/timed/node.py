"""A node on a timed wire (one bus instance): its queues, error counters and tallies."""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass, field

import can

from canbus.framebits import FrameBits
from canbus.timed.faults import BUS_OFF_ABOVE, PASSIVE_ABOVE, BitErrors
from canbus.timed.stats import NodeStats


class Waiter:
    """A thread waiting on a wire: a lock of its own, held until someone lets it go."""

    __slots__ = ("alarm", "roused", "timed")

    def __init__(self) -> None:
        self.alarm = threading.Lock()
        self.alarm.acquire()
        self.timed = False
        """It sleeps until a set time (the end of a frame), not only until woken."""
        self.roused = False
        """Someone released its lock (and took it off the node's list)."""


_local = threading.local()


def waiter() -> Waiter:
    """The calling thread's waiter (a thread waits for one thing at a time)."""
    try:
        me: Waiter = _local.waiter
    except AttributeError:
        me = _local.waiter = Waiter()
    return me


@dataclass(eq=False, slots=True)
class Pending:
    """A frame in a transmit queue."""

    template: can.Message
    """What receivers get (timestamp and ``is_rx`` set per copy)."""
    can_id: int
    flags: int
    """``canbus.framebits`` flags (``F_ESI`` is added while the transmitter is error passive)."""
    dlc: int
    data: bytes
    key: int
    """Arbitration key: the smallest wins."""
    submitted: float = 0.0
    attempts: int = 0
    bits: FrameBits | None = None
    """Its bits, counted when it first goes on the wire."""


@dataclass(eq=False)
class Node:
    """One bus instance's controller: a FIFO transmit queue, a receive queue, counters."""

    index: int
    name: str
    fd: bool
    receive_own: bool
    receive_error_frames: bool
    acknowledge: bool
    tx_limit: int
    rx_limit: int
    """0: unbounded."""
    errors: BitErrors
    room: threading.Condition
    """Notified when the transmit queue shrinks (shares the wire's lock)."""
    room_waiters: int = 0
    """Senders waiting on :attr:`room` (none: no notification needed)."""
    tx: deque[Pending] = field(default_factory=deque)
    rx: deque[can.Message] = field(default_factory=deque)
    """Frames delivered and not yet read (the wire's lock guards it)."""
    waiters: list[Waiter] = field(default_factory=list)
    """Readers blocked in ``recv`` on this node."""
    open: bool = True
    tec: int = 0
    rec: int = 0
    bus_off: bool = False
    recovery: int = 0
    """Sequences of 11 recessive bits seen while bus off."""
    counted_until: float = 0.0
    """Wire time up to which idle bits were counted towards recovery."""
    not_before: float = 0.0
    """Earliest start of this node's next frame (suspend transmission, recovery)."""
    sent: int = 0
    received: int = 0
    lost_overflow: int = 0
    tx_errors: int = 0
    bus_off_count: int = 0

    @property
    def passive(self) -> bool:
        return self.tec > PASSIVE_ABOVE or self.rec > PASSIVE_ABOVE

    @property
    def state(self) -> can.BusState:
        if self.bus_off:
            return can.BusState.ERROR
        return can.BusState.PASSIVE if self.passive else can.BusState.ACTIVE

    def understands(self, fd: bool) -> bool:
        """Receives (and acknowledges) a frame of this kind: open, not bus off, FD if needed."""
        return self.open and not self.bus_off and (self.fd or not fd)

    def transmit_error(self, *, ack_error: bool, at: float) -> None:
        """Error frame on its frame; bus off past TEC 255, recovery counted from ``at``."""
        self.tx_errors += 1
        if not (ack_error and self.passive):
            self.tec += 8
        if self.tec > BUS_OFF_ABOVE:
            self.bus_off, self.recovery, self.counted_until = True, 0, at
            self.bus_off_count += 1

    def receive_error(self) -> None:
        self.rec = min(self.rec + 1, 255)

    def recover(self, at: float) -> None:
        self.bus_off, self.tec, self.rec, self.recovery = False, 0, 0, 0
        self.not_before = max(self.not_before, at)

    def snapshot(self) -> NodeStats:
        return NodeStats(name=self.name, fd=self.fd, state=self.state, tec=self.tec,
                         rec=self.rec, sent=self.sent, received=self.received,
                         lost_overflow=self.lost_overflow, errors=self.tx_errors,
                         bus_off_count=self.bus_off_count, pending=len(self.tx))
