"""``skin plan``: bus load of N patches at a rate, mode and bitrate."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict
from typing import Any


def _plan(args: argparse.Namespace) -> int:
    from canbus.busload import plan
    from skin.atomic import atomic_write
    from skin.errors import ConfigError

    for field in ("patches", "rate", "bitrate", "target"):
        if not getattr(args, field) > 0:
            raise ConfigError(field, f"must be positive, got {getattr(args, field)}")
    data_bitrate = (args.data_bitrate or args.bitrate) if args.fd else None
    result = plan(args.patches, args.rate, args.mode, args.bitrate,
                  data_bitrate=data_bitrate, target_pct=args.target)
    bus = f"CAN FD {args.bitrate}/{data_bitrate} bit/s" if args.fd else f"CAN {args.bitrate} bit/s"
    print(f"{result.patches} patches x {result.rate_hz:g} Hz, mode {result.mode}, {bus}")
    print(f"frames per sample: {result.frames_per_sample}")
    print(f"frames/s:          {result.frames_per_s:,.0f}")
    print(f"bus load:          {result.load_best_pct:.1f} % (no stuffing) to "
          f"{result.load_worst_pct:.1f} % (worst-case stuffing)")
    print(f"max rate under {result.target_pct:g} %: {result.max_rate_hz:,.1f} Hz per patch")
    if result.over_target:
        print(f"warning: worst-case load {result.load_worst_pct:.1f} % is above the "
              f"{result.target_pct:g} % target; lower the rate to {result.max_rate_hz:,.1f} Hz "
              "or use fewer patches per bus", file=sys.stderr)
    if args.json:
        record = asdict(result) | {"over_target": result.over_target}
        with atomic_write(args.json) as handle:
            handle.write(json.dumps(record, indent=2).encode() + b"\n")
    return 0


def add_subparser(subparsers: Any) -> None:
    parser = subparsers.add_parser("plan", help="bus load for N patches at a rate and bitrate")
    parser.add_argument("--patches", type=int, required=True, metavar="N")
    parser.add_argument("--rate", type=float, required=True, metavar="HZ",
                        help="samples per second per patch")
    parser.add_argument("--mode", choices=("z", "xyz"), default="xyz")
    parser.add_argument("--bitrate", type=int, default=1_000_000, metavar="B",
                        help="(nominal) bitrate in bit/s (default 1000000)")
    parser.add_argument("--fd", action="store_true",
                        help="CAN FD: one frame per sample, data phase at --data-bitrate")
    parser.add_argument("--data-bitrate", type=int, default=None, metavar="B",
                        help="CAN FD data-phase bitrate (default: --bitrate)")
    parser.add_argument("--target", type=float, default=70.0, metavar="PCT",
                        help="target bus load in %% (default 70)")
    parser.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    parser.set_defaults(func=_plan)
