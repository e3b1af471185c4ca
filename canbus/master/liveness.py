"""Heartbeat consumer: which patches are alive, which are lost, which have just booted.

A watched node is *lost* when no heartbeat came for ``lost_after`` = 1.5 heartbeat
periods; the check runs every quarter period, so a node whose heartbeat stops is
reported lost at most 1.75 periods after its last heartbeat: within two periods.
A boot-up message (state byte 0x00) is reported as a boot; the first heartbeat of a
node that was lost (or never heard) is reported as a return, with its NMT state; a
heartbeat that enters or leaves OPERATIONAL (the previous one, or the boot-up, was on
the other side) is reported as a change (``on_change``, optional). :meth:`expect`
counts a node alive from now without a heartbeat (another master has just started it):
it is lost if no heartbeat follows within ``lost_after``.
Callbacks run on the network's notifier thread (boot, return) or on the monitor's own
thread (lost): they must only record and hand work on, never wait for the bus.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import canopen

from canbus.worker import Worker

logger = logging.getLogger(__name__)

BOOTUP = 0x00
OPERATIONAL = 0x05
LOST_AFTER_PERIODS = 1.5
CHECKS_PER_PERIOD = 4


@dataclass
class _Watch:
    alive: bool = False
    lost: bool = False  # marked lost by a check, no heartbeat since
    state: int | None = None  # NMT state byte of the last heartbeat
    last_seen: float = 0.0  # monotonic
    last_heartbeat: float | None = None  # time.time() of the last heartbeat
    lost_after_s: float | None = None  # None: its heartbeat period is not known, not judged


class HeartbeatMonitor:
    """Consumes the heartbeats (0x700 + node-ID) of the watched nodes."""

    def __init__(self, network: canopen.Network, period_ms: int, *,
                 on_boot: Callable[[int], None], on_lost: Callable[[int], None],
                 on_return: Callable[[int, int], None],
                 on_change: Callable[[int, int], None] | None = None,
                 clock: Callable[[], float] = time.monotonic,
                 self_checking: bool = True) -> None:
        self.network = network
        self.period_s = period_ms / 1000.0
        self.lost_after_s = LOST_AFTER_PERIODS * self.period_s
        self.on_boot, self.on_lost, self.on_return = on_boot, on_lost, on_return
        self.on_change = on_change
        self.clock = clock
        self.self_checking = self_checking  # False: the owner calls check() on its clock
        self._watches: dict[int, _Watch] = {}
        self._lock = threading.Lock()
        self._checker = Worker(self._run, "heartbeat-monitor")

    def watch(self, node_id: int, *, judged: bool = True) -> None:
        """Consume ``node_id``'s heartbeats; ``judged=False``: do not call it lost until
        :meth:`judge` says its heartbeat period is ours (a host has not written 0x1017 yet,
        and the node may beat at its own default period meanwhile)."""
        lost_after = self.lost_after_s if judged else None
        with self._lock:
            self._watches.setdefault(node_id, _Watch(last_seen=self.clock(),
                                                     lost_after_s=lost_after))
        self.network.subscribe(0x700 + node_id, self.on_heartbeat)

    def judge(self, node_id: int, judged: bool) -> None:
        """Judge (from now) or stop judging a watched node's silence by our period."""
        with self._lock:
            watch = self._watches.get(node_id)
            if watch is not None:
                watch.lost_after_s = self.lost_after_s if judged else None
                watch.last_seen = self.clock()

    def unwatch(self, node_id: int) -> None:
        with self._lock:
            self._watches.pop(node_id, None)
        self._unsubscribe(node_id)

    def _unsubscribe(self, node_id: int) -> None:
        if self.on_heartbeat in self.network.subscribers.get(0x700 + node_id, []):
            self.network.unsubscribe(0x700 + node_id, self.on_heartbeat)

    def expect(self, node_id: int) -> None:
        """Count a watched node alive from now: lost unless a heartbeat comes in time."""
        with self._lock:
            watch = self._watches.get(node_id)
            if watch is not None:
                watch.alive, watch.lost, watch.last_seen = True, False, self.clock()
                watch.lost_after_s = self.lost_after_s

    def alive(self, node_id: int) -> bool:
        with self._lock:
            watch = self._watches.get(node_id)
            return watch is not None and watch.alive

    def lost(self, node_id: int) -> bool:
        """The node was found overdue and has not been heard since (its latest fact: read
        it when deciding, never trust an ``on_lost`` that may be older than a heartbeat)."""
        with self._lock:
            watch = self._watches.get(node_id)
            return watch is not None and watch.lost

    def state(self, node_id: int) -> int | None:
        """The NMT state byte of the node's last heartbeat (None: never heard)."""
        with self._lock:
            watch = self._watches.get(node_id)
            return None if watch is None else watch.state

    def last_heartbeat(self, node_id: int) -> float | None:
        """``time.time()`` of the node's last heartbeat (None: never heard)."""
        with self._lock:
            watch = self._watches.get(node_id)
            return None if watch is None else watch.last_heartbeat

    def on_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """canopen subscriber of 0x700 + node-ID."""
        if len(data) != 1:
            return
        node_id, state = can_id - 0x700, data[0] & 0x7F
        with self._lock:
            watch = self._watches.get(node_id)
            if watch is None:
                return
            returned = not watch.alive and state != BOOTUP
            changed = (watch.alive and watch.state is not None
                       and (watch.state == OPERATIONAL) != (state == OPERATIONAL))
            watch.alive, watch.lost, watch.state = True, False, state
            watch.last_seen, watch.last_heartbeat = self.clock(), time.time()
        if state == BOOTUP:
            self.on_boot(node_id)
        elif returned:
            self.on_return(node_id, state)
        elif changed and self.on_change is not None:
            self.on_change(node_id, state)

    def check(self) -> list[int]:
        """Mark and report the nodes whose heartbeat is overdue; returns them."""
        now = self.clock()
        with self._lock:
            lost = [n for n, w in self._watches.items() if w.alive
                    and w.lost_after_s is not None and now - w.last_seen > w.lost_after_s]
            for node_id in lost:
                self._watches[node_id].alive = False
                self._watches[node_id].lost = True
        for node_id in lost:
            self.on_lost(node_id)
        return lost

    def start(self) -> None:
        if self.self_checking:
            self._checker.start()

    def stop(self) -> None:
        """Stop checking and consuming; what was heard stays readable."""
        self._checker.stop()
        with self._lock:
            nodes = list(self._watches)
        for node_id in nodes:
            self._unsubscribe(node_id)

    def _run(self) -> None:
        interval = self.period_s / CHECKS_PER_PERIOD
        while not self._checker.stopping.wait(interval):
            try:
                self.check()
            except Exception:  # a failing callback must not end the monitor
                logger.exception("heartbeat check failed")
