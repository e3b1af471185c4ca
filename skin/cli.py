"""The ``skin`` command: one entry point, one module per subcommand.

Each subcommand module has ``add_subparser(subparsers)`` and sets
``func``; modules are imported when the parser is built, but they import the
heavy packages (sim, decoder, canbus) only inside their ``func``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from skin import __version__
from skin.errors import SkinError

SUBCOMMANDS = (
    "sim", "model", "train", "bench", "plan", "eds", "run", "demo", "sniff", "replay", "tare",
    "decode", "dataset", "calibrate",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="skin",
        description="Robot-skin middleware over CAN: simulate, decode, run and sniff patches.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the traceback on errors")
    subparsers = parser.add_subparsers(title="subcommands", metavar="COMMAND", required=True)
    for name in SUBCOMMANDS:
        try:
            module = importlib.import_module(f"skin.commands.{name}")
        except ModuleNotFoundError as err:
            if err.name != f"skin.commands.{name}":
                raise
            continue
        module.add_subparser(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code = args.func(args)
    except KeyboardInterrupt:
        print("skin: interrupted", file=sys.stderr)
        return 130
    except (SkinError, OSError) as err:
        if args.debug:
            raise
        print(f"skin: error: {err}", file=sys.stderr)
        return 1
    return int(code or 0)


if __name__ == "__main__":
    sys.exit(main())
