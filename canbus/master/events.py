"""The host's events besides forces: a patch's state changed, a patch sent an EMCY.

``host.on_event(callback)`` calls ``callback(event)`` with a :class:`StateEvent` or an
:class:`EmcyEvent`, on the thread that saw it (canopen's notifier, the heartbeat
consumer, a set-up worker), after the host recorded it: keep it short. An exception is
logged and counted in ``host.callback_errors``; the other callbacks still run.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class StateEvent:
    """Patch ``patch`` on bus ``bus`` went from ``previous`` to ``state`` (``PatchHealth``)."""

    patch: int
    bus: str
    state: str
    previous: str
    error: str | None
    time: float  # time.time()


@dataclass(frozen=True)
class EmcyEvent:
    """An EMCY from patch ``patch``: CiA 301 error code, error register, manufacturer data."""

    patch: int
    bus: str
    code: int
    register: int
    data: bytes
    time: float  # time.time() when the host received it


HostEvent = StateEvent | EmcyEvent
EventCallback = Callable[[HostEvent], None]


class EventHooks:
    """The event callbacks; the list is replaced, never mutated, so :meth:`emit` reads it
    without a lock."""

    def __init__(self) -> None:
        self._callbacks: tuple[EventCallback, ...] = ()
        self._lock = threading.Lock()
        self.errors = 0

    def add(self, callback: EventCallback) -> None:
        with self._lock:
            self._callbacks = (*self._callbacks, callback)

    def remove(self, callback: EventCallback) -> None:
        with self._lock:
            self._callbacks = tuple(c for c in self._callbacks if c is not callback)

    def emit(self, event: HostEvent) -> None:
        for callback in self._callbacks:
            try:
                callback(event)
            except Exception:
                self.errors += 1
                logger.exception("event callback %r failed", callback)
