"""One object per bus, shared by every user of the bus in the process, gone with the bus."""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable
from typing import Generic, TypeVar

import can

T = TypeVar("T")


class PerBus(Generic[T]):
    """``per_bus(bus)``: the one ``T`` of ``bus``, made by ``make(bus)`` on first use."""

    def __init__(self, make: Callable[[can.BusABC], T]) -> None:
        self._make = make
        self._made: weakref.WeakKeyDictionary[can.BusABC, T] = weakref.WeakKeyDictionary()
        self._lock = threading.Lock()

    def __call__(self, bus: can.BusABC) -> T:
        with self._lock:
            found = self._made.get(bus)
            if found is None:
                found = self._made[bus] = self._make(bus)
            return found

    def get(self, bus: can.BusABC) -> T | None:
        """The bus's ``T`` if one was made, without making one."""
        with self._lock:
            return self._made.get(bus)
