"""The ``skin`` command: one entry point, one module per subcommand.

Each subcommand module has ``add_subparser(subparsers)`` and sets
``func``; modules are imported when the parser is built, but they import the
heavy packages (sim, decoder, canbus) only inside their ``func``.

Logging (``-v``, ``-q``, ``--log-level``, before or after the subcommand) is configured
here, once (``skin.commands.common.logs``). Exit status: 0 when a command did its work or a
long-running one was stopped (Ctrl-C, SIGTERM, SIGHUP: it prints its summary and writes
its ``--json``); 1 on an error (one line on stderr; ``--debug`` shows the traceback);
2 on a usage error (argparse); 130 when a stop interrupts a command whose work has an
end (train, bench, ...): nothing half-written is left.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Iterator, Sequence
from typing import Any

from skin import __version__
from skin.commands.common.argtypes import OneLineParser
from skin.commands.common.logs import add_logging_arguments, after_error, configured_logging
from skin.commands.common.signals import stop_signal_name, stop_signals_interrupt
from skin.errors import SkinError, printable_line

SUBCOMMANDS = (
    "sim", "model", "train", "eval", "bench", "plan", "eds", "run", "demo", "sniff", "replay",
    "tare", "decode", "view", "dataset", "calibrate", "lss", "compare",
)


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="skin",
        description="Robot-skin middleware over CAN: simulate, decode, run and sniff patches.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the traceback on errors")
    add_logging_arguments(parser, subcommand=False)
    subparsers = parser.add_subparsers(title="subcommands", metavar="COMMAND", required=True)
    for name in SUBCOMMANDS:
        try:
            module = importlib.import_module(f"skin.commands.{name}")
        except ModuleNotFoundError as err:
            if err.name != f"skin.commands.{name}":
                raise
            continue
        module.add_subparser(subparsers)
    for command in _commands(subparsers):
        add_logging_arguments(command, subcommand=True)
    return parser


def _commands(
    subparsers: argparse._SubParsersAction[Any],
) -> Iterator[argparse.ArgumentParser]:
    """Every (sub-)subcommand's parser: ``sim``, ``sim dataset``, ``sim run``, ..."""
    for command in dict.fromkeys(subparsers.choices.values()):  # aliases share a parser
        yield command
        for action in command._actions:
            if isinstance(action, argparse._SubParsersAction):
                yield from _commands(action)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    with configured_logging(args):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    """The command, and the one line its failure ends in (its held warnings after it,
    ``skin.commands.common.logs``)."""
    try:
        with stop_signals_interrupt():
            code = args.func(args)
    except KeyboardInterrupt as err:
        if getattr(args, "runs_until_stopped", False):  # stopped while starting or ending:
            # still how such a command is meant to end (docs/cli.md, exit status)
            print(f"skin: stopped ({stop_signal_name(err)})", file=sys.stderr)
            return 0
        return _failed(f"skin: interrupted ({stop_signal_name(err)})", 130)
    except (SkinError, OSError) as err:
        if args.debug:
            raise
        return _failed(f"skin: error: {one_line(err)}")
    except MemoryError:
        if args.debug:
            raise
        return _failed("skin: error: out of memory (a request larger than this machine can "
                       "hold)")
    except Exception as err:  # a library's error nothing above turned into a sentence
        if args.debug:
            raise
        return _failed(f"skin: error: {type(err).__name__}: {one_line(err)} (unexpected; "
                       "--debug shows where)")
    return int(code or 0)


def _failed(line: str, code: int = 1) -> int:
    print(line, file=sys.stderr)
    after_error()
    return code


def one_line(err: BaseException) -> str:
    """The error's message on one line."""
    return printable_line(str(err)) or type(err).__name__


if __name__ == "__main__":
    sys.exit(main())
