"""Python's logging for the ``skin`` command: configured once, here, never by the library.

Every library module (canbus, decoder, sim, skin) logs through
``logging.getLogger(__name__)`` and leaves configuration to the application. The command
sends every record to stderr as ``2025-01-01 12:00:00.123 WARNING canbus.tools.recorder: text``.

Levels: by default the library (canbus, decoder, sim, python-can, canopen) shows
warnings and errors, and the commands' own loggers (``skin.commands.*``) also their INFO
progress lines. ``-v`` shows INFO from everything, ``-vv`` DEBUG; ``-q`` shows errors
only, ``-qq`` nothing below CRITICAL; ``--log-level LEVEL`` sets one level for all.

A command that fails says one thing, the error: its warnings (WARNING records of any logger,
and the commands' own ``warning: ...`` lines, :func:`warn`) are held from its start until
it says its arguments and outputs are checked (:func:`checks_passed`, before a long run
starts) or until it ends well; then they go out in order. When it fails first, the error
line is printed alone and the held warnings follow it as DEBUG lines (``-vv``).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
from collections.abc import Iterator
from typing import TextIO

COMMANDS_LOGGER = "skin.commands"
LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL")
FORMAT = "%(asctime)s.%(msecs)03d %(levelname)s %(name)s: %(message)s"
DATE_FORMAT = "%Y-%m-%d %H:%M:%S"
_BY_VERBOSITY = {-2: logging.CRITICAL, -1: logging.ERROR, 0: logging.WARNING,
                 1: logging.INFO, 2: logging.DEBUG}


class _Formatter(logging.Formatter):
    """The log format; a :func:`warn` line as it is."""

    def format(self, record: logging.LogRecord) -> str:
        if getattr(record, "plain", False):
            return record.getMessage()
        return super().format(record)


class _StderrHandler(logging.StreamHandler[TextIO]):
    """Writes to whatever ``sys.stderr`` is at the time (pytest swaps it per test); holds
    warnings back until the command's checks passed (module docstring)."""

    def __init__(self) -> None:
        super().__init__(sys.stderr)
        self.setFormatter(_Formatter(FORMAT, DATE_FORMAT))
        self.held: list[logging.LogRecord] | None = []
        """Warnings waiting for the checks; None once they passed."""

    def emit(self, record: logging.LogRecord) -> None:
        if self.held is not None and record.levelno >= logging.WARNING:
            self.held.append(record)  # under the handler's lock (Handler.handle)
            return
        self.stream = sys.stderr
        super().emit(record)

    def let_through(self) -> None:
        """Print the held warnings; later ones at once. (Not ``release``: a Handler's
        ``release`` is its lock's.)"""
        with self.lock:  # type: ignore[union-attr]  # created by Handler.__init__
            held, self.held = self.held or [], None
            for record in held:
                self.emit(record)

    def demote(self) -> None:
        """After an error: the held warnings as DEBUG lines, if DEBUG is shown; later
        warnings at once."""
        with self.lock:  # type: ignore[union-attr]
            held, self.held = self.held or [], None
            for record in held:
                if logging.getLogger(record.name).isEnabledFor(logging.DEBUG):
                    record.levelno, record.levelname = logging.DEBUG, "DEBUG"
                    self.emit(record)


def _stderr_handlers() -> list[_StderrHandler]:
    return [h for h in logging.getLogger().handlers if isinstance(h, _StderrHandler)]


def checks_passed() -> None:
    """The command's arguments and outputs are checked, its work begins: the warnings held
    since it started go out now, later ones at once (module docstring)."""
    for handler in _stderr_handlers():
        handler.let_through()


def after_error() -> None:
    """The command failed and its error line is printed: its held warnings follow as DEBUG."""
    for handler in _stderr_handlers():
        handler.demote()


def warn(text: str) -> None:
    """A command's own ``warning: ...`` line on stderr, held as a warning record is."""
    logging.getLogger(COMMANDS_LOGGER).warning(text, extra={"plain": True})


def add_logging_arguments(parser: argparse.ArgumentParser, *, subcommand: bool) -> None:
    """``-v``, ``-q`` and ``--log-level``; on a subcommand they default to nothing, so
    ``skin -v run`` and ``skin run -v`` both work and neither overrides the other."""
    none: tuple[object, object, object] = (argparse.SUPPRESS,) * 3 if subcommand \
        else (0, 0, None)
    group = parser.add_argument_group("logging")
    group.add_argument("-v", "--verbose", action="count", default=none[0],
                       help="show INFO log lines of every package (-vv: DEBUG)")
    group.add_argument("-q", "--quiet", action="count", default=none[1],
                       help="show errors only (-qq: nothing below CRITICAL)")
    group.add_argument("--log-level", type=str.upper, choices=LEVELS, default=none[2],
                       metavar="LEVEL", help="one log level for everything: "
                       f"{', '.join(LEVELS)} (overrides -v/-q)")


def log_levels(verbose: int, quiet: int, level: str | None) -> tuple[int, int]:
    """(level of the root logger, level of the commands' loggers)."""
    if level is not None:
        chosen = getattr(logging, level)
        return chosen, chosen
    verbosity = max(-2, min(2, verbose - quiet))
    root = _BY_VERBOSITY[verbosity]
    return root, (logging.INFO if verbosity == 0 else root)


@contextlib.contextmanager
def configured_logging(args: argparse.Namespace) -> Iterator[None]:
    """Log to stderr at the levels ``args`` asks for while inside; as it was afterwards
    (a process configures it once; ``skin.cli.main`` called in-process leaves no trace)."""
    root_level, commands_level = log_levels(getattr(args, "verbose", 0) or 0,
                                            getattr(args, "quiet", 0) or 0,
                                            getattr(args, "log_level", None))
    root, commands = logging.getLogger(), logging.getLogger(COMMANDS_LOGGER)
    before = root.level, commands.level
    handler = _StderrHandler()
    root.addHandler(handler)
    root.setLevel(root_level)
    commands.setLevel(commands_level)
    logging.captureWarnings(True)  # warnings.warn() becomes a WARNING record, same format
    try:
        yield
    finally:
        handler.let_through()  # the command ended well, or stopped (else after_error came first)
        logging.captureWarnings(False)
        root.removeHandler(handler)
        root.setLevel(before[0])
        commands.setLevel(before[1])


class _Held(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.NOTSET)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


@contextlib.contextmanager
def held_back(*names: str) -> Iterator[None]:
    """Hold the log records of the loggers ``names`` (python-can's ``can``, ``canopen``)
    back while inside: a library's own lines around a failure (a missing driver, a bus
    "not properly shut down", an EDS warning) would only surround the one line that says
    what is wrong. Dropped when the block raises, logged as usual when it succeeds."""
    held = _Held()
    loggers = [logging.getLogger(name) for name in names]
    before = [logger.propagate for logger in loggers]
    for logger in loggers:
        logger.addHandler(held)
        logger.propagate = False
    try:
        yield
    finally:
        for logger, propagate in zip(loggers, before, strict=True):
            logger.removeHandler(held)
            logger.propagate = propagate
    for record in held.records:
        logging.getLogger(record.name).handle(record)
