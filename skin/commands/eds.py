"""``skin eds check FILE...``: validate EDS files (paths or shipped names)."""

from __future__ import annotations

import argparse
import sys
from typing import Any


def _check(args: argparse.Namespace) -> int:
    from canbus.od import eds_file
    from canbus.tools.edscheck import check
    from skin.commands.common.logs import held_back
    from skin.errors import printable_line

    failed = 0
    for name in args.files:
        with eds_file(name) as path, held_back("canopen"):
            problems = check(path)
        for problem in problems:
            print(printable_line(f"{name}: {problem}"), file=sys.stderr)
        if problems:
            failed += 1
        else:
            print(f"{name}: ok")
    return 1 if failed else 0


def add_subparser(subparsers: Any) -> None:
    parser = subparsers.add_parser("eds", help="EDS files: validate")
    group = parser.add_subparsers(title="eds commands", metavar="ACTION", required=True)
    check = group.add_parser("check", help="validate EDS files beyond what canopen checks")
    check.add_argument("files", nargs="+", metavar="FILE",
                       help="an EDS path or a shipped name (skin-patch, skin-forces)")
    check.set_defaults(func=_check)
