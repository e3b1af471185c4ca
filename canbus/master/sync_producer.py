"""SYNC producer: a thread that sends SYNC (COB-ID 0x080) every period, with a counter.

Cycle ``k`` (1, 2, ...) carries the counter byte ``k % 240 + 1`` (CiA 301: 1..240) or
no data. ``on_sync(cycle, counter, timestamp)`` runs just before the frame goes out,
with the ``time.time()`` read right before sending: a patch answers a SYNC only after
it was sent, so no PDO of cycle ``k`` can reach the data plane before it knows cycle
``k`` began. Deadlines are absolute (no drift). A SYNC sent so late that the next one
would follow it within half a period is an overrun: the schedule restarts from it, so
no cycle is ever shorter than half a period (a burst of SYNCs would give the patches
no time to answer, and their answers would count for the wrong cycle).

:class:`SyncFollower` is the listen-only counterpart: a ``can.Listener`` that opens a
cycle for every SYNC another master sends, with the frame's timestamp and counter byte.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import can

from canbus.answers import counter_of_sync
from canbus.txmessage import TxMessage
from canbus.worker import Worker

logger = logging.getLogger(__name__)

SYNC_COB_ID = 0x080
COUNTER_OVERFLOW = 240

OnSync = Callable[[int, int, float], None]


def sync_counter(cycle: int) -> int:
    """The SYNC counter byte of ``cycle``: 1..240."""
    return cycle % COUNTER_OVERFLOW + 1


class SyncProducer:
    """Sends SYNC on ``bus`` every ``period_s`` seconds once started."""

    def __init__(self, bus: can.BusABC, period_s: float, *, on_sync: OnSync,
                 counter: bool = True) -> None:
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s!r}")
        self.bus = bus
        self.period_s = period_s
        self.on_sync = on_sync
        self.counter = counter
        self.cycle = 0
        self.overruns = 0
        self.send_errors = 0
        self._worker = Worker(self._run, "sync-producer")

    def start(self) -> None:
        self._worker.start()

    def stop(self) -> None:
        self._worker.stop()

    def send_one(self) -> None:
        """Open the next cycle and send its SYNC."""
        self.cycle += 1
        count = sync_counter(self.cycle) if self.counter else 0
        msg = TxMessage.data_frame(SYNC_COB_ID, bytes([count]) if self.counter else b"")
        self.on_sync(self.cycle, count, time.time())
        try:
            self.bus.send(msg)
        except can.CanError as err:
            self.send_errors += 1
            logger.warning("SYNC %d not sent: %s", self.cycle, err)

    def _run(self) -> None:
        deadline = time.monotonic()
        while True:
            try:
                self.send_one()
            except Exception:  # on_sync failing must not stop the clock of the whole bus
                logger.exception("SYNC cycle %d failed", self.cycle)
            deadline += self.period_s
            now = time.monotonic()
            if deadline - now < 0.5 * self.period_s:  # late: no cycle shorter than half a period
                self.overruns += 1
                deadline = now + self.period_s
            if self._worker.stopping.wait(max(0.0, deadline - now)):
                return


class SyncFollower(can.Listener):
    """Calls ``on_sync(cycle, counter, timestamp)`` for every SYNC received (cycle 1, 2, ...).

    A SYNC is a standard data frame on 0x080 with no data or the counter byte (CiA 301);
    ``counter`` is that byte, or 0 without one, and ``timestamp`` the frame's. Put it on
    the notifier before the listeners of the PDOs that answer the SYNC, so that each cycle
    opens before its PDOs are seen, as :class:`SyncProducer` opens it before sending.
    """

    def __init__(self, on_sync: OnSync) -> None:
        self.on_sync = on_sync
        self.cycle = 0

    def on_message_received(self, msg: can.Message) -> None:
        counter = counter_of_sync(msg)
        if counter is None:
            return
        self.cycle += 1
        try:
            self.on_sync(self.cycle, counter, msg.timestamp)
        except Exception:  # an exception in a listener would end the notifier's thread
            logger.exception("SYNC cycle %d failed", self.cycle)
