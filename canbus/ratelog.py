"""Log lines that cannot flood: the first few of a kind, then a count of the rest.

A bus that delivers garbage at 3,000 frames/s, or a patch that floods EMCYs, must not
write 3,000 lines a second for as long as it lasts. :class:`RateLimitedLog` logs the first
``burst`` events of each key in every ``interval_s``, holds the rest back, and says how
many it held back with the next line it lets through (or at :meth:`flush`).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Hashable
from dataclasses import dataclass

INTERVAL_S = 10.0
BURST = 3
MAX_KEYS = 1024  # keys remembered at most: a stream of distinct keys must not grow this


@dataclass
class _Window:
    start: float
    logged: int = 0
    held: int = 0


class RateLimitedLog:
    """At most ``burst`` lines per key per ``interval_s`` on ``logger``; thread-safe."""

    def __init__(self, logger: logging.Logger, *, interval_s: float = INTERVAL_S,
                 burst: int = BURST, clock: Callable[[], float] = time.monotonic) -> None:
        self.logger = logger
        self.interval_s = interval_s
        self.burst = burst
        self.clock = clock
        self.held_back = 0  # lines not written, over the log's life
        self._windows: dict[Hashable, _Window] = {}
        self._lock = threading.Lock()

    def log(self, level: int, key: Hashable, msg: str, *args: object) -> bool:
        """Log ``msg % args`` unless ``key`` had its ``burst`` lines in this interval;
        True if it was written."""
        now = self.clock()
        with self._lock:
            window = self._windows.get(key)
            if window is None or now - window.start >= self.interval_s:
                held = window.held if window is not None else 0
                if len(self._windows) >= MAX_KEYS and key not in self._windows:
                    self._windows.pop(next(iter(self._windows)))
                window = self._windows[key] = _Window(now)
            else:
                held = 0
            if window.logged >= self.burst:
                window.held += 1
                self.held_back += 1
                return False
            window.logged += 1
        if held:
            msg += f" ({held} more like it held back in the last {self.interval_s:g} s)"
        self.logger.log(level, msg, *args)
        return True

    def flush(self, level: int = logging.INFO) -> None:
        """Say how many lines of each key were held back and not yet told."""
        with self._lock:
            held = [(key, w.held) for key, w in self._windows.items() if w.held]
            for window in self._windows.values():
                window.held = 0
        for key, count in held:
            self.logger.log(level, "%s: %d more log lines like the last held back", key, count)
