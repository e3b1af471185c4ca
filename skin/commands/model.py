"""``skin model approx``: the exact tripod against the paper's small-strain reading."""

from __future__ import annotations

import argparse
import json
from typing import Any

from skin.atomic import atomic_write
from skin.commands.common import argtypes


def add_subparser(subparsers: Any) -> None:
    parser = subparsers.add_parser("model", help="inspect the sensor model")
    group = parser.add_subparsers(metavar="ACTION", required=True)
    approx = group.add_parser(
        "approx",
        help="force error of the paper's small-strain approximation at 5, 10 and 20 %% strain",
    )
    approx.add_argument("--json", type=argtypes.output_file, metavar="FILE",
                        help="also write the table as JSON")
    approx.set_defaults(func=_approx)


def _approx(args: argparse.Namespace) -> int:
    from skin.smallstrain import approximation_table

    rows = approximation_table()
    print("| load | peak strain | force (N) | paper Eq. 9 error | linearised truss error |")
    print("|---|---|---|---|---|")
    for row in rows:
        if row.force_N is None or row.paper_err_pct is None or row.linear_err_pct is None:
            print(f"| {row.load} | {row.strain_pct:.0f} % | collapses first | – | – |")
            continue
        print(
            f"| {row.load} | {row.strain_pct:.0f} % | {row.force_N:.2f} | "
            f"{row.paper_err_pct:.1f} % | {row.linear_err_pct:.1f} % |"
        )
    if args.json:
        with atomic_write(args.json) as handle:
            handle.write(json.dumps([row.__dict__ for row in rows], indent=2).encode())
    return 0
