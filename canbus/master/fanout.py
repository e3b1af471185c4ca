"""Force frames to the API: callbacks and bounded iterators, never blocking the data plane."""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
from collections.abc import Callable, Iterator

from canbus.master.dataplane import ForceFrame

logger = logging.getLogger(__name__)

FrameCallback = Callable[[ForceFrame], None]


class _FrameQueue:
    """A bounded queue that drops its oldest frame rather than block the data plane."""

    def __init__(self, maxsize: int) -> None:
        self.queue: queue.Queue[ForceFrame | None] = queue.Queue(maxsize)
        self.dropped = 0

    def put(self, item: ForceFrame | None) -> None:
        while True:
            try:
                self.queue.put_nowait(item)
                return
            except queue.Full:
                with contextlib.suppress(queue.Empty):
                    self.queue.get_nowait()
                    self.dropped += 1


class FrameFanout:
    """Hands every published frame to the callbacks and to each open iterator's queue.

    The lists of callbacks and queues are replaced, never mutated, so :meth:`publish`
    (the data plane's thread) reads them without a lock. A failing callback is logged and
    counted in :attr:`callback_errors`; a frame an iterator had no room for is counted in
    :attr:`dropped`.
    """

    def __init__(self) -> None:
        self._callbacks: list[FrameCallback] = []
        self._queues: list[_FrameQueue] = []
        self._lock = threading.Lock()
        self.callback_errors = 0
        self.dropped = 0

    def add_callback(self, callback: FrameCallback) -> None:
        with self._lock:
            self._callbacks = [*self._callbacks, callback]

    def remove_callback(self, callback: FrameCallback) -> None:
        with self._lock:
            self._callbacks = [c for c in self._callbacks if c is not callback]

    def iterate(self, maxsize: int, timeout: float | None,
                running: Callable[[], bool]) -> Iterator[ForceFrame]:
        """Frames from now on until ``timeout`` passes without one, :meth:`close`, or
        ``running()`` is false and the queue is empty."""
        q = _FrameQueue(maxsize)
        with self._lock:
            self._queues = [*self._queues, q]
        return self._drain(q, timeout, running)

    def _drain(self, q: _FrameQueue, timeout: float | None,
               running: Callable[[], bool]) -> Iterator[ForceFrame]:
        try:
            while running() or not q.queue.empty():
                try:
                    item = q.queue.get(timeout=timeout)
                except queue.Empty:
                    return
                if item is None:
                    return
                yield item
        finally:
            with self._lock:
                self._queues = [x for x in self._queues if x is not q]

    def publish(self, frame: ForceFrame) -> None:
        for callback in self._callbacks:
            try:
                callback(frame)
            except Exception:
                self.callback_errors += 1
                logger.exception("force callback %r failed", callback)
        for q in self._queues:
            before = q.dropped
            q.put(frame)
            self.dropped += q.dropped - before

    def close(self) -> None:
        """End every open iterator (after the frames it already holds)."""
        with self._lock:
            queues = list(self._queues)
        for q in queues:
            q.put(None)
