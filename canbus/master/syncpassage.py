"""Where the bus passed the SYNCs a host sent: the SYNC producer announces each SYNC before
it sends it, and the data plane opens its cycle only once the bus shows it passed: the SYNC's
echo in the host's own receive stream (matched by its counter), or a frame stamped after it
(docs/dataplane.md, "When a cycle closes")."""

from __future__ import annotations

import math
from collections import deque

Sync = tuple[int, int, float]
"""A SYNC: its cycle, its counter byte, the ``time.time()`` it was sent at."""


class SyncPassage:
    """The SYNCs sent whose passage the bus has not shown yet, oldest first. Not locked: the
    data plane calls it under its own lock."""

    def __init__(self) -> None:
        self._unpassed: deque[Sync] = deque()
        self._by_echo = False
        self.next_t = math.inf
        """A frame stamped at or after this passes the oldest SYNC (inf: none is waiting,
        or the echo says where it passed)."""

    @property
    def by_echo(self) -> bool:
        """The bus hands back the echo of each SYNC with its counter (udp_multicast): the
        echo, not a time stamp, is where it passed."""
        return self._by_echo

    @by_echo.setter
    def by_echo(self, value: bool) -> None:
        self._by_echo = value
        self._next()

    def __bool__(self) -> bool:
        return bool(self._unpassed)

    def sent(self, sync: Sync) -> None:
        self._unpassed.append(sync)
        self._next()

    def passed_until(self, until: float) -> list[Sync]:
        """The SYNCs sent at or before ``until``, now passed, oldest first."""
        unpassed, out = self._unpassed, []
        while unpassed and unpassed[0][2] <= until:
            out.append(unpassed.popleft())
        self._next()
        return out

    def echoed(self, counter: int) -> list[Sync]:
        """The SYNC whose echo carries ``counter``, with any sent before it whose echo was
        lost, oldest first; nothing for the echo of a SYNC that passed already."""
        unpassed: deque[Sync] = self._unpassed
        if not any(sync[1] == counter for sync in unpassed):
            return []
        out = []
        while unpassed:
            out.append(unpassed.popleft())
            if out[-1][1] == counter:
                break
        self._next()
        return out

    def _next(self) -> None:
        self.next_t = self._unpassed[0][2] if self._unpassed and not self._by_echo else math.inf
