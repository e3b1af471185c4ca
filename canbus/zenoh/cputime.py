"""CPU time of the publishing thread and of Zenoh's own (native) threads, for the figures.

Linux: a thread's CPU is read from ``/proc/self/task/TID/schedstat`` (nanoseconds on a
CPU); elsewhere the native threads count 0 and only the Python thread is measured.
"""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

_TASKS = Path("/proc/self/task")


class ThreadClock:
    """A context manager that adds the CPU time the current thread spends inside it."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self._start = 0.0

    def __enter__(self) -> ThreadClock:
        self._start = time.thread_time()
        return self

    def __exit__(self, *exc: object) -> None:
        self.seconds += time.thread_time() - self._start


def native_threads() -> set[int]:
    """The thread IDs of this process (empty where /proc is not there)."""
    try:
        return {int(name) for name in os.listdir(_TASKS)}
    except OSError:
        return set()


def python_threads() -> set[int]:
    """The thread IDs of this process's Python threads."""
    return {t.native_id for t in threading.enumerate() if t.native_id is not None}


def threads_cpu(tids: set[int]) -> float:
    """CPU seconds the threads ``tids`` have used so far (threads that ended count 0)."""
    total = 0
    for tid in tids:
        try:
            total += int((_TASKS / str(tid) / "schedstat").read_text().split()[0])
        except (OSError, ValueError, IndexError):
            continue
    return total / 1e9
