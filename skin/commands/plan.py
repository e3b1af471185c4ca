"""``skin plan``: the load N patches put on their buses, every frame counted, and how many
buses they need under the target load, classic CAN and CAN FD side by side
(``canbus.sizing``)."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

from skin.commands.common import argtypes

if TYPE_CHECKING:
    from canbus.busload import BusPlan, Plan
    from canbus.sizing import Sizing

KIND_NAMES = {"patch_pdo": "patch PDO", "force_pdo": "force PDO", "sync": "SYNC",
              "heartbeat": "heartbeat"}


def _nodes(ids: tuple[int, ...]) -> str:
    if not ids:
        return "none"
    if ids == tuple(range(ids[0], ids[-1] + 1)) and len(ids) > 2:
        return f"{ids[0]}-{ids[-1]}"
    return ",".join(map(str, ids))


def _describe_bus(bus: BusPlan, plan: Plan) -> list[str]:
    who = []
    if bus.patches:
        who.append(f"patches {_nodes(bus.patches)}")
    if bus.force_nodes:
        who.append(f"force nodes {_nodes(bus.force_nodes)}")
    kinds = ", ".join(f"{KIND_NAMES[k]} {v:,.0f}" for k, v in bus.frames_per_s.items())
    verdict = ("does not fit" if not bus.fits else
               f"fits, above the {plan.target_pct:g} % target" if bus.over_target else
               f"fits, under the {plan.target_pct:g} % target")
    period = f" per {1e3 / plan.rate_hz:.3g} ms cycle" if plan.rate_hz > 0 else ""
    return [
        f"{bus.name} ({'; '.join(who)}): {sum(bus.frames_per_s.values()):,.0f} frames/s "
        f"({kinds})",
        f"  load:  {bus.load_best_pct:.1f} % (no stuffing) to {bus.load_worst_pct:.1f} % "
        f"(worst-case stuffing): {verdict}",
        f"  cycle: {bus.cycle_ms_best:.2f} to {bus.cycle_ms_worst:.2f} ms of wire{period}",
        f"  max under {plan.target_pct:g} %: {bus.max_rate_hz:,.1f} Hz per "
        f"{'patch' if bus.patches else 'force node'}, "
        f"{bus.max_patch_samples_per_s:,.0f} samples/s on this bus",
    ]


def _record(plan: Plan) -> dict[str, Any]:
    """The plan as JSON: every figure, each bus's frames summed by kind (not listed)."""
    record = asdict(plan)
    for bus in record["buses"]:
        del bus["frames"]
    return record


def _plan(args: argparse.Namespace) -> int:
    from canbus.busload import plan
    from skin.atomic import atomic_write
    from skin.errors import ConfigError

    for field in ("patches", "rate", "bitrate", "target", "buses"):
        if not getattr(args, field) > 0:
            raise ConfigError(f"--{field}", f"must be positive, got {getattr(args, field)}")
    for field in ("heartbeat_ms", "force_heartbeat_ms"):
        if getattr(args, field) < 0:
            raise ConfigError(f"--{field.replace('_', '-')}",
                              f"must be 0 (off) or positive, got {getattr(args, field)}")
    if args.buses > args.patches:
        raise ConfigError("--buses", f"{args.buses} buses for {args.patches} patches: "
                                     "a bus would carry none")
    data_bitrate = args.data_bitrate if args.fd else None
    if data_bitrate is not None and data_bitrate < args.bitrate:
        raise ConfigError("--data-bitrate", f"{data_bitrate} is below the nominal bitrate "
                                            f"{args.bitrate}")
    result = plan(args.patches, args.rate, args.mode, args.bitrate,
                  data_bitrate=data_bitrate, target_pct=args.target, forces=args.forces,
                  buses=args.buses, heartbeat_ms=args.heartbeat_ms,
                  force_heartbeat_ms=args.force_heartbeat_ms, contact=not args.no_contact)
    bus = (f"CAN FD {args.bitrate}/{data_bitrate} bit/s" if data_bitrate
           else f"CAN {args.bitrate} bit/s")
    forces = {"same-bus": "forces on each patch's bus", "other-bus": "forces on their own bus",
              "none": "forces not counted"}[args.forces]
    if args.forces != "none":
        forces += " without the contact PDO" if args.no_contact else " with the contact PDO"
    buses = f"{args.buses} bus{'es' if args.buses > 1 else ''}" + (
        " and a force bus" if args.forces == "other-bus" else "")
    print(f"{result.patches} patches x {result.rate_hz:g} Hz, mode {result.mode}, {bus}, "
          f"{buses}, {forces}")
    print(f"frames per sample: {result.frames_per_sample} patch + "
          f"{result.force_frames_per_sample} force; heartbeats every {args.heartbeat_ms} ms "
          f"(patches), {args.force_heartbeat_ms} ms (force nodes)")
    for each in result.buses:
        print("\n".join(_describe_bus(each, result)))
    if len(result.buses) > 1:
        print(f"worst bus: {result.worst_bus}, {result.load_worst_pct:.1f} % worst case")
    sizings = _sizings(args)
    _print_sizing(args, sizings)
    advice = _advice(sizings)
    if not result.fits:
        print(f"warning: the traffic does not fit: {result.worst_bus} needs "
              f"{result.load_best_pct:.1f} to {result.load_worst_pct:.1f} % of its wire; lower "
              f"the rate to {result.max_rate_hz:,.1f} Hz{advice}", file=sys.stderr)
    elif result.over_target:
        print(f"warning: worst-case load {result.load_worst_pct:.1f} % is above the "
              f"{result.target_pct:g} % target; lower the rate to {result.max_rate_hz:,.1f} Hz"
              f"{advice}", file=sys.stderr)
    if args.json:
        record = _record(result) | {"sizing": {("fd" if s.fd else "classic"): asdict(s)
                                               for s in sizings}}
        with atomic_write(args.json) as handle:
            handle.write(json.dumps(record, indent=2).encode() + b"\n")
    return 0


def _sizings(args: argparse.Namespace) -> list[Sizing]:
    """The buses needed at the target, classic CAN and CAN FD (``canbus.sizing``)."""
    from canbus.sizing import size

    return [size(args.patches, args.rate, args.mode, args.bitrate, data_bitrate=fd,
                 target_pct=args.target, forces=args.forces, heartbeat_ms=args.heartbeat_ms,
                 force_heartbeat_ms=args.force_heartbeat_ms, contact=not args.no_contact)
            for fd in (None, args.data_bitrate)]


def _kind(s: Sizing) -> str:
    return f"CAN FD {s.bitrate:,}/{s.data_bitrate:,} bit/s" if s.fd else \
        f"CAN {s.bitrate:,} bit/s"


def _buses(s: Sizing) -> str:
    if s.buses is None or s.force_buses is None:
        return "none fits"
    return f"{s.buses}" + (f" + {s.force_buses} for forces" if s.force_buses else "")


def _print_sizing(args: argparse.Namespace, sizings: list[Sizing]) -> None:
    """Classic and CAN FD side by side: buses needed, patches a bus, load, highest rate."""
    from skin.commands.common.tables import show

    rows = []
    for s in sizings:
        low, high = s.patches_per_bus
        rows.append([_kind(s), _buses(s), f"{low}" if low == high else f"{low}-{high}",
                     f"{s.load_worst_pct:.1f} %", f"{s.max_rate_hz:,.1f} Hz"])
    show(f"buses needed for {args.patches} patches x {args.rate:g} Hz under the "
         f"{args.target:g} % target (worst-case stuffing)",
         ["bus", "buses", "patches a bus", "worst-case load a bus", "highest rate a bus carries"],
         rows, caption="none fits: one patch alone on a bus is above the target; its highest "
         "rate is shown" if any(s.buses is None for s in sizings) else "")


def _count(n: int, what: str) -> str:
    return f"{n} {what}{'es' if n != 1 else ''}"


def _advice(sizings: list[Sizing]) -> str:
    fitting = [_count(s.buses, "bus") + (f" and {_count(s.force_buses, 'force bus')}"
                                         if s.force_buses else "") + f" of {_kind(s)}"
               for s in sizings if s.buses is not None and s.force_buses is not None]
    return f", or use {' or '.join(fitting)} (above)" if fitting else ""


def add_subparser(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "plan", help="bus load of N patches at a rate: patch and force PDOs, SYNC, heartbeats")
    parser.add_argument("--patches", type=argtypes.count("patches", 1, 100_000), required=True,
                        metavar="N")
    parser.add_argument("--rate", type=argtypes.rate_hz, required=True, metavar="HZ",
                        help="samples per second per patch (the SYNC rate)")
    parser.add_argument("--mode", choices=("z", "xyz"), default="xyz")
    parser.add_argument("--bitrate", type=argtypes.bitrate, default=1_000_000, metavar="B",
                        help="(nominal) bitrate in bit/s (default 1000000)")
    parser.add_argument("--fd", action="store_true",
                        help="CAN FD: one PDO per sample, data phase at --data-bitrate")
    parser.add_argument("--data-bitrate", type=argtypes.bitrate, default=5_000_000, metavar="B",
                        help="CAN FD data-phase bitrate (default 5000000)")
    parser.add_argument("--forces", choices=("same-bus", "other-bus", "none"),
                        default="same-bus",
                        help="where the host republishes the forces (default same-bus)")
    parser.add_argument("--no-contact", action="store_true",
                        help="the host publishes no contact summary ([contact] enabled = "
                             "false): 7 force PDOs per sample, not 8 (CAN FD: 57 bytes, not 64)")
    parser.add_argument("--buses", type=argtypes.count("buses", 1, 100_000), default=1, metavar="N",
                        help="spread the patches over N buses, each with its own SYNC")
    parser.add_argument("--heartbeat-ms", type=argtypes.heartbeat_ms, default=100, metavar="MS",
                        help="patch heartbeat period (default 100; 0 = off)")
    parser.add_argument("--force-heartbeat-ms", type=argtypes.heartbeat_ms, default=1000,
                        metavar="MS",
                        help="force node heartbeat period (default 1000; 0 = off)")
    parser.add_argument("--target", type=argtypes.percent, default=70.0, metavar="PCT",
                        help="target bus load in %% (default 70)")
    parser.add_argument("--json", type=argtypes.output_file, metavar="FILE",
                        help="also write the figures as JSON")
    parser.set_defaults(func=_plan)
