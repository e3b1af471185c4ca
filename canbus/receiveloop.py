"""A notifier that does not die: :class:`ReceiveLoop`, and canopen networks read by one.

python-can's ``Notifier`` ends its thread on the first exception from ``recv`` or from a
listener. :class:`ReceiveLoop` is a ``can.Notifier`` whose thread survives anything
``recv`` or a listener raises (counted, logged rate-limited; a failing listener does not
keep the frame from the others). On a plain bus a failing ``recv`` is tried again at
once while a failing spell is young (a burst of bad datagrams drains without a pause),
then after a growing pause (never spinning a core); a
:class:`~canbus.busio.BusGoneError` (a :class:`~canbus.busio.ResilientBus` that could not
be opened again) ends it, with :attr:`~can.Notifier.exception` set and ``on_gone``
called. :func:`connect` gives a ``canopen.Network`` a :class:`ReceiveLoop` in place of
the ``Notifier`` that ``Network.connect()`` builds, so canopen's side cannot die either.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

import can
import canopen

from canbus.busio import BusGoneError, ReceiveStats, ResilientBus, describe
from canbus.ratelog import RateLimitedLog

logger = logging.getLogger(__name__)

PAUSE_AFTER_S = 0.2  # a plain bus failing this long, nothing received: pause between tries
PAUSE_MIN_S, PAUSE_MAX_S = 0.001, 0.5
"""A burst of garbage fails one recv per datagram, at once: it drains without a pause (a
pause per failure would make 100 bad datagrams cost many seconds); a bus that keeps
failing is tried again after a growing pause, never spinning a core."""


class ReceiveLoop(can.Notifier):
    """A ``can.Notifier`` that survives its bus and its listeners (module docstring).

    ``on_gone(err)`` is called, on the loop's thread, when the bus is gone for good
    (a :class:`ResilientBus` that could not be opened again); :attr:`exception` is then
    set, as python-can's sets it when its thread dies.
    """

    def __init__(self, bus: can.BusABC, listeners: Iterable[Any], timeout: float = 1.0, *,
                 name: str | None = None,
                 on_gone: Callable[[BaseException], None] | None = None) -> None:
        self.name = name or str(getattr(bus, "channel_info", "bus"))
        self.on_gone = on_gone
        self.stats = ReceiveStats()
        self._halt = threading.Event()
        self._log = RateLimitedLog(logger)
        super().__init__(bus, listeners, timeout)

    def report(self) -> dict[str, Any]:
        """The loop's counters, with a :class:`ResilientBus`'s own added in."""
        out = self.stats.as_dict()
        for bus in self._bus_list:
            if isinstance(bus, ResilientBus):
                mine = bus.stats.as_dict()
                for key, value in mine.items():
                    if isinstance(value, int) and isinstance(out.get(key), int):
                        out[key] += value
                    elif value is not None:
                        out[key] = value
        return out

    def add_bus(self, bus: can.BusABC) -> None:
        super().add_bus(bus)
        reader = self._readers[-1]
        if isinstance(reader, threading.Thread):  # named as python-can names its own
            reader.name = f'Notifier for bus "{bus.channel_info}"'

    def stop(self, timeout: float = 5.0) -> None:
        self._halt.set()
        super().stop(timeout)

    def _rx_thread(self, bus: can.BusABC) -> None:
        recv, timeout, lock = bus.recv, self.timeout, self._lock
        failures, pause = 0, PAUSE_MIN_S
        spell = 0.0  # time.monotonic() of the spell's first failure
        while not self._stopped:
            try:
                msg = recv(timeout)
            except BusGoneError as err:
                self._gone(err)
                return
            except Exception as err:  # whatever a driver raises: counted and survived
                failures += 1
                if failures == 1:
                    spell, pause = time.monotonic(), PAUSE_MIN_S
                self._recv_failed(err, failures)
                if time.monotonic() - spell >= PAUSE_AFTER_S:
                    self._halt.wait(pause)
                    pause = min(2 * pause, PAUSE_MAX_S)
                continue
            if failures:
                self._log.log(logging.INFO, "back", "bus %s: receiving again after %d "
                              "error(s)", self.name, failures)
                failures = 0
                self.stats.failing_since = None
            if msg is None:
                continue
            with lock:
                for listener in self.listeners:
                    try:
                        listener(msg)
                    except Exception as err:
                        self._listener_failed(listener, err)

    def _recv_failed(self, err: Exception, failures: int) -> None:
        stats = self.stats
        stats.errors += 1
        stats.last_error = describe(err)
        if failures == 1:  # once a spell: its end says how many there were
            stats.failing_since = time.time()
            self._log.log(logging.WARNING, "recv", "bus %s: receiving failed (%s); going on",
                          self.name, stats.last_error)

    def _listener_failed(self, listener: Any, err: Exception) -> None:
        self.stats.listener_errors += 1
        self.stats.last_error = describe(err)
        self._log.log(logging.ERROR, ("listener", id(listener)), "bus %s: listener %r "
                      "failed on a frame (%s); the others still got it", self.name,
                      listener, self.stats.last_error)

    def _gone(self, err: BusGoneError) -> None:
        self.exception = err
        self.stats.gone = str(err)
        if self.on_gone is not None:
            try:
                self.on_gone(err)
            except Exception:
                logger.exception("bus %s: on_gone failed", self.name)


def disconnect(network: canopen.Network) -> None:
    """``network.disconnect()``, which raises what ended its notifier (canopen's
    ``check()``) after it has stopped everything: a bus gone for good is told elsewhere."""
    with contextlib.suppress(BusGoneError):
        network.disconnect()


def connect(network: canopen.Network, *, name: str | None = None,
            on_gone: Callable[[BaseException], None] | None = None) -> canopen.Network:
    """``network.connect()`` on the bus it was built with, but with a :class:`ReceiveLoop`
    for its notifier (canopen's own dies with its bus)."""
    if network.bus is None:
        raise ValueError("the network has no bus: canopen.Network(bus) first")
    network.notifier = ReceiveLoop(network.bus, network.listeners, network.NOTIFIER_CYCLE,
                                   name=name, on_gone=on_gone)
    return network

