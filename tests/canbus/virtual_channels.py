"""Events on python-can's virtual channels that tests wait for (no sleeping on a guess)."""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Callable
from typing import TextIO

import can
import can.interfaces.virtual

from tests.support.rigs.waiting import wait_until


def listening(channel: str) -> bool:
    """A ``can.Notifier`` (a sniffer's, a host's) receives on ``channel``."""
    return any(t.name.startswith("Notifier for bus") and channel in t.name
               for t in threading.enumerate())


def read_out(channel: str, *mine: can.BusABC) -> bool:
    """Every bus of ``channel`` but ``mine`` has taken every frame sent to it: a receiver
    stopped now loses nothing (a virtual bus queues each frame for every other bus)."""
    queues = can.interfaces.virtual.channels.get(channel, [])
    own = {id(bus.queue) for bus in mine}  # type: ignore[attr-defined]
    return all(q.empty() for q in queues if id(q) not in own)


def ctrl_c() -> None:
    """SIGINT to the main thread, as Ctrl-C: unlike ``_thread.interrupt_main`` it also wakes
    a wait blocked in the kernel (a command waiting for its end)."""
    signal.pthread_kill(threading.main_thread().ident or 0, signal.SIGINT)


class _Watched:
    """A text stream that passes everything on and notes when ``text`` went through."""

    def __init__(self, stream: TextIO, text: str, seen: threading.Event) -> None:
        self.stream, self.text, self.seen = stream, text, seen

    def write(self, data: str) -> int:
        if self.text in data:
            self.seen.set()
        return self.stream.write(data)

    def __getattr__(self, name: str) -> object:
        return getattr(self.stream, name)


def run_until_done(argv: list[str], traffic: Callable[[], None], *,
                   ready: str = "Ctrl-C stops") -> int:
    """``skin ARGV`` in this (the main) thread while ``traffic()`` runs in another; when
    ``traffic`` returns (or fails: re-raised here) and the command has said ``ready`` (on
    stdout or stderr: from then on a stop ends it normally), it gets Ctrl-C, as a user
    stops it. Its exit status. The command's time limit is then not the test's clock."""
    from skin.cli import main

    failures: list[BaseException] = []
    returned, said = threading.Event(), threading.Event()

    def run() -> None:
        try:
            traffic()
            wait_until(lambda: said.is_set() or returned.is_set(), what=f"skin said {ready!r}")
        except BaseException as err:
            failures.append(err)
        finally:
            if not returned.is_set():
                ctrl_c()

    worker = threading.Thread(target=run)
    out, err = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = _Watched(out, ready, said), _Watched(err, ready, said)  # type: ignore[assignment]
    worker.start()
    try:
        code = main(argv)
    finally:
        sys.stdout, sys.stderr = out, err
        returned.set()
        try:
            worker.join(60.0)
        except KeyboardInterrupt:  # ours, come as the command returned by itself
            worker.join(60.0)
    if failures:
        raise failures[0]
    return code
