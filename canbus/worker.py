"""A daemon thread with a stop flag: the start and stop that the SYNC producer, the heartbeat
monitor and the patch server's sample clock share."""

from __future__ import annotations

import threading
from collections.abc import Callable


class Worker:
    """Runs ``target`` on a daemon thread named ``name`` from :meth:`start` until :meth:`stop`.

    ``target`` returns once :attr:`stopping` is set; it waits on it between rounds
    (``while not worker.stopping.wait(interval): ...``), so a stop never waits out a round.
    """

    def __init__(self, target: Callable[[], None], name: str) -> None:
        self.target = target
        self.name = name
        self.stopping = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def running(self) -> bool:
        """Started and not stopped yet."""
        return self._thread is not None

    def start(self) -> None:
        """Start the thread (again, after a stop)."""
        self.stopping.clear()
        self._thread = threading.Thread(target=self.target, name=self.name, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Set :attr:`stopping` and wait for the thread to end. A worker never started, or
        stopped already, stays stopped."""
        self.stopping.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
