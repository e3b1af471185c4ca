"""Stop signals: SIGTERM and SIGHUP end a command the way Ctrl-C does.

systemd, docker, ``timeout`` and a closed terminal stop a process with SIGTERM or SIGHUP,
whose default action kills it on the spot: no summary, no ``--json``, a recording's last
batch and the temporary file of an atomic write left behind. :func:`stop_signals_interrupt`
turns both into :class:`Stopped`, a ``KeyboardInterrupt``, in the main thread, so every
``except KeyboardInterrupt`` and ``finally`` that handles Ctrl-C handles them too.
``skin.cli.main`` holds it around every command; :func:`until_stopped` marks the part of
a long-running command that a stop ends normally (its summary and ``--json`` follow).

A stop signal the process was started with ignored (``nohup`` ignores SIGHUP) stays
ignored. Only the first SIGTERM or SIGHUP interrupts: later ones are ignored until the command
ends, so a service manager that signals twice does not cut the clean stop short
(Ctrl-C, SIGINT, still interrupts it, as Python does by default; SIGKILL always works).
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from types import FrameType

logger = logging.getLogger(__name__)

STOP_SIGNALS = (signal.SIGTERM, signal.SIGHUP)


class Stopped(KeyboardInterrupt):
    """A stop signal (SIGTERM, SIGHUP) raised in the main thread, as Ctrl-C raises
    ``KeyboardInterrupt``."""

    def __init__(self, signum: int) -> None:
        self.signal = signal.Signals(signum)
        super().__init__(self.signal.name)


def stop_signal_name(err: KeyboardInterrupt) -> str:
    """``SIGTERM``/``SIGHUP`` for :class:`Stopped`, ``SIGINT`` for Ctrl-C."""
    return err.signal.name if isinstance(err, Stopped) else signal.SIGINT.name


@contextlib.contextmanager
def stop_signals_interrupt() -> Iterator[None]:
    """SIGTERM and SIGHUP raise :class:`Stopped` in the main thread while inside; the
    previous handlers come back on leaving. Outside the main thread (where Python cannot
    set handlers) it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: FrameType | None) -> None:
        for sig in previous:  # one stop: a second signal must not cut the clean stop
            signal.signal(sig, signal.SIG_IGN)
        raise Stopped(signum)

    # A signal the process was started with ignored stays ignored: ``nohup skin run`` must
    # outlive its terminal's SIGHUP
    previous = {sig: signal.signal(sig, interrupt) for sig in STOP_SIGNALS
                if signal.getsignal(sig) is not signal.SIG_IGN}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


@dataclass
class StopReason:
    """Which signal ended an :func:`until_stopped` block; None if it ended by itself."""

    signal: str | None = None


@contextlib.contextmanager
def until_stopped() -> Iterator[StopReason]:
    """Run the block until it ends or Ctrl-C/SIGTERM/SIGHUP stops it; a stop is not an
    error: it is swallowed, logged, and named in the yielded :class:`StopReason`."""
    from skin.commands.common.logs import checks_passed

    checks_passed()  # the command's work begins: its warnings go out as they come
    reason = StopReason()
    try:
        yield reason
    except KeyboardInterrupt as err:
        reason.signal = stop_signal_name(err)
        logger.info("stopping on %s", reason.signal)
