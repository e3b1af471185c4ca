"""A bus that does not stay dead: :class:`ResilientBus` re-opens the bus it wraps.

python-can's ``Notifier`` ends its thread on the first exception from ``recv`` or from a
listener: one datagram that udp_multicast cannot unpack, one error frame it refuses, an
``ENETDOWN`` when the interface goes down. What reads the bus then goes on running deaf.
:class:`ResilientBus` wraps the bus an ``opener`` returns: an exception from its ``recv``
is counted, logged (once a failing spell) and survived; a bus that keeps failing
(:data:`REOPEN_AFTER` failures over :data:`REOPEN_AFTER_S` with nothing received in
between) is shut down and opened again, with back-off; one that cannot be had back within
``give_up_s`` is *gone*: :attr:`ResilientBus.gone` is set, ``recv`` raises
:class:`BusGoneError` and ``send`` ``can.CanOperationError``, and a command ends with a
non-zero status so that its service manager restarts it. What reads it is a
``canbus.receiveloop.ReceiveLoop``, a notifier that survives its bus and its listeners.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import can
import can.broadcastmanager

from canbus.ratelog import RateLimitedLog
from canbus.rxfilter import refresh as refresh_receive_filter
from skin.errors import SkinError

logger = logging.getLogger(__name__)

REOPEN_AFTER = 3  # consecutive failures ...
REOPEN_AFTER_S = 0.2  # ... over at least this long, nothing received between: re-open
GIVE_UP_S = 3.0  # failing this long, re-opens included: the bus is gone
BACKOFF_MIN_S, BACKOFF_MAX_S = 0.1, 1.0  # between re-open attempts

class BusGoneError(can.CanOperationError):
    """The bus failed and could not be opened again: receiving has ended for good."""


@dataclass
class ReceiveStats:
    """What receiving from one bus has survived."""

    errors: int = 0  # exceptions from recv, survived
    listener_errors: int = 0  # exceptions from a listener, survived
    reopens: int = 0  # the bus shut down and opened again
    failed_opens: int = 0  # attempts to open it again that failed
    periodic_send_errors: int = 0  # a heartbeat's send failed (the task went on)
    last_error: str | None = None
    failing_since: float | None = None  # time.time() of the first failure of a spell
    gone: str | None = None  # why receiving ended for good

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def describe(err: BaseException) -> str:
    """``Type: message``, with the cause a python-can error wraps (``could not unpack
    received message (ValueError: ...)``); our own errors are their one line."""
    if isinstance(err, SkinError):
        return str(err)
    text = f"{type(err).__name__}: {err}"
    cause = err.__cause__ or err.__context__
    if isinstance(err, can.CanError) and cause is not None and str(cause) \
            and str(cause) not in text:
        text += f" ({type(cause).__name__}: {cause})"
    return text


class ResilientBus(can.BusABC):
    """The bus ``opener()`` returns (or ``bus``, opened already), re-opened by ``opener``
    when it keeps failing; see the module docstring. ``prepare(bus)`` runs on each bus
    ``opener`` opens (a socket's receive buffer, ...).

    Everything but ``recv``, ``send`` and ``shutdown`` goes to the bus in use
    (:attr:`wrapped`): ``fileno``, ``state``, a timed bus's ``wire_stats`` ... Filters set
    on this bus are set again on a re-opened one.
    """

    def __init__(self, opener: Callable[[], can.BusABC], *, name: str = "bus",
                 bus: can.BusABC | None = None, give_up_s: float = GIVE_UP_S,
                 prepare: Callable[[can.BusABC], object] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._ready = False
        self._opener = opener
        self._prepare = prepare
        self._bus: can.BusABC | None = bus if bus is not None else self._open()
        self.name = name
        self.give_up_s = give_up_s
        self.clock = clock
        self.stats = ReceiveStats()
        self.gone = threading.Event()
        self.on_reopen: list[Callable[[ResilientBus], None]] = []
        self.channel_info = self._bus.channel_info
        self._can_protocol = self._bus.protocol
        self._spell: float | None = None  # clock() of the first failure since a success
        self._failures = 0  # in the spell
        self._reopened = False  # in the spell
        self._retry_at = 0.0
        self._backoff = BACKOFF_MIN_S
        self._closed = threading.Event()
        self._log = RateLimitedLog(logger)
        self._own_filters = False  # filters were set on this bus: set them on a new one
        super().__init__(channel=getattr(self._bus, "channel", None) or name)
        self._ready = True

    def _open(self) -> can.BusABC:
        bus = self._opener()
        if self._prepare is not None:
            self._prepare(bus)
        return bus

    @property
    def wrapped(self) -> can.BusABC | None:
        """The bus in use (None while it is being opened again)."""
        return self._bus

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):
            raise AttributeError(name)
        bus = self.__dict__.get("_bus")
        if bus is None:
            raise AttributeError(name)
        return getattr(bus, name)

    # -- python-can ------------------------------------------------------------------

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """The next frame, or None (time-out, or a failure survived); raises only
        :class:`BusGoneError`."""
        if self.gone.is_set():
            raise BusGoneError(f"bus {self.name}: gone ({self.stats.gone})")
        bus = self._bus
        if bus is None:
            self._reopen(timeout)
            return None
        try:
            msg = bus.recv(timeout)
        except Exception as err:  # whatever a driver raises: counted and survived
            self._failed(err, timeout)
            return None
        if self._spell is not None:
            self._recovered()
        return msg

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self.recv(timeout), True

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        bus = self._bus
        if bus is None:
            reason = self.stats.gone or "being opened again"
            raise can.CanOperationError(f"bus {self.name}: {reason}")
        bus.send(msg, timeout)

    def _send_periodic_internal(
            self, msgs: Sequence[can.Message] | can.Message, period: float,
            duration: float | None = None, autostart: bool = True,
            modifier_callback: Callable[[can.Message], None] | None = None,
    ) -> can.broadcastmanager.CyclicSendTaskABC:
        """python-can's thread-based task, sending through :class:`_PeriodicSender`: a
        heartbeat producer's thread must not end when one send fails (python-can's ends
        for good), nor log a traceback each period while the bus is opened again."""
        lock = self.__dict__.setdefault("_lock_send_periodic", threading.Lock())
        return can.broadcastmanager.ThreadBasedCyclicSendTask(
            bus=_PeriodicSender(self), lock=lock, messages=msgs, period=period,  # type: ignore[arg-type]
            duration=duration, autostart=autostart, modifier_callback=modifier_callback)

    def set_filters(self, filters: Any = None) -> None:
        self._filters = filters or None
        if self._ready:
            self._own_filters = True
            if self._bus is not None:
                self._bus.set_filters(filters)

    def fileno(self) -> int:
        if self._bus is None:
            raise NotImplementedError("the bus is being opened again")
        return self._bus.fileno()

    def flush_tx_buffer(self) -> None:
        if self._bus is not None:
            self._bus.flush_tx_buffer()

    @property
    def state(self) -> can.BusState:
        return can.BusState.ERROR if self._bus is None else self._bus.state

    @state.setter
    def state(self, new_state: can.BusState) -> None:
        if self._bus is not None:
            self._bus.state = new_state

    def shutdown(self) -> None:
        self._closed.set()
        super().shutdown()
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.shutdown()

    # -- failures --------------------------------------------------------------------

    def _failed(self, err: Exception, timeout: float | None) -> None:
        now = self.clock()
        stats = self.stats
        stats.errors += 1
        stats.last_error = describe(err)
        if self._spell is None:
            self._spell, self._failures = now, 0
            stats.failing_since = time.time()
        self._failures += 1
        if self._failures == 1:  # once a spell: its end says how many there were
            self._log.log(logging.WARNING, "recv", "bus %s: receiving failed (%s); going on",
                          self.name, stats.last_error)
        if self._closed.is_set():
            return
        if now - self._spell >= self.give_up_s and self._reopened:
            self._give_up(f"failing for {now - self._spell:.1f} s after {stats.reopens} "
                          f"re-open(s): {stats.last_error}")
        if self._failures >= REOPEN_AFTER and now - self._spell >= REOPEN_AFTER_S:
            if not self._reopened or now >= self._retry_at:
                self._close_failing()
                self._reopen(timeout)
                return
            self._closed.wait(_bounded(self._retry_at - now, timeout))

    def _close_failing(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            with contextlib.suppress(Exception):
                bus.shutdown()
        self._reopened = True

    def _reopen(self, timeout: float | None) -> None:
        now = self.clock()
        if now < self._retry_at:
            self._closed.wait(_bounded(self._retry_at - now, timeout))
            return
        if self._closed.is_set():
            return
        stats = self.stats
        try:
            bus = self._open()
        except Exception as err:
            stats.failed_opens += 1
            stats.last_error = describe(err)
            self._schedule_retry(now)
            self._log.log(logging.WARNING, "open", "bus %s: cannot open it again (%s); next "
                          "try in %.1f s", self.name, stats.last_error, self._retry_at - now)
            if self._spell is not None and now - self._spell >= self.give_up_s:
                self._give_up(f"cannot open it again for {now - self._spell:.1f} s: "
                              f"{stats.last_error}")
            return
        if self._own_filters:
            bus.set_filters(self._filters)
        self._bus = bus
        stats.reopens += 1
        self._schedule_retry(now)
        logger.warning("bus %s: opened again after %d receive error(s)", self.name,
                       stats.errors)
        refresh_receive_filter(self)  # udp_multicast: the kernel filter of own frames
        for hook in list(self.on_reopen):
            try:
                hook(self)
            except Exception:
                logger.exception("bus %s: a re-open hook failed", self.name)

    def _schedule_retry(self, now: float) -> None:
        self._retry_at = now + self._backoff
        self._backoff = min(2 * self._backoff, BACKOFF_MAX_S)

    def _recovered(self) -> None:
        assert self._spell is not None
        logger.info("bus %s: receiving again (%d error(s) over %.2f s)", self.name,
                    self._failures, self.clock() - self._spell)
        self._spell, self._failures, self._reopened = None, 0, False
        self._backoff = BACKOFF_MIN_S
        self.stats.failing_since = None

    def _give_up(self, reason: str) -> None:
        self.stats.gone = reason
        self._close_failing()
        self.gone.set()
        logger.error("bus %s: gone (%s)", self.name, reason)
        raise BusGoneError(f"bus {self.name}: gone ({reason})")


class _PeriodicSender:
    """What a periodic task sends through: the bus's ``send``, its failures counted and
    logged (rate-limited) instead of raised."""

    def __init__(self, bus: ResilientBus) -> None:
        self.bus = bus

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        bus = self.bus
        try:
            bus.send(msg, timeout)
        except Exception as err:
            bus.stats.periodic_send_errors += 1
            bus._log.log(logging.WARNING, ("periodic", msg.arbitration_id),
                         "bus %s: periodic frame 0x%03X not sent (%s); the next goes on time",
                         bus.name, msg.arbitration_id, describe(err))


def _bounded(wait_s: float, timeout: float | None) -> float:
    return max(0.0, wait_s if timeout is None else min(wait_s, timeout))


def gone(buses: Iterable[object]) -> str | None:
    """Why one of ``buses`` (a :class:`ResilientBus`) is gone for good; None while every
    one is heard. Others are never gone here (a :class:`ReceiveLoop` says for them)."""
    for bus in buses:
        if isinstance(bus, ResilientBus) and bus.gone.is_set():
            return f"bus {bus.name}: gone ({bus.stats.gone})"
    return None
