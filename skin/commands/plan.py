"""``skin plan``: the load N patches put on their buses, every frame counted, and how many
buses they need under the target load, classic CAN and CAN FD side by side
(``canbus.sizing``)."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

from skin.commands.common import argtypes
from skin.commands.common.logs import warn

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


def _check(args: argparse.Namespace) -> None:
    """ConfigError for values argparse alone cannot judge, naming the flag."""
    from skin.errors import ConfigError

    for field in ("patches", "rate", "bitrate", "target"):
        if not getattr(args, field) > 0:
            raise ConfigError(f"--{field}", f"must be positive, got {getattr(args, field)}")
    for field in ("heartbeat_ms", "force_heartbeat_ms"):
        if getattr(args, field) < 0:
            raise ConfigError(f"--{field.replace('_', '-')}",
                              f"must be 0 (off) or positive, got {getattr(args, field)}")
    if args.buses is not None and args.buses > args.patches:
        raise ConfigError("--buses", f"{args.buses} buses for {args.patches} patches: "
                                     "a bus would carry none")
    if args.fd and args.data_bitrate < args.bitrate:
        raise ConfigError("--data-bitrate", f"{args.data_bitrate} is below the nominal "
                                            f"bitrate {args.bitrate}")


def _buses_under_max_load(args: argparse.Namespace) -> int:
    """The fewest buses of the chosen kind that keep every bus under ``--max-load``."""
    from canbus.sizing import size
    from skin.errors import ConfigError

    sized = size(args.patches, args.rate, args.mode, args.bitrate,
                 data_bitrate=args.data_bitrate if args.fd else None,
                 target_pct=args.max_load, forces=args.forces, heartbeat_ms=args.heartbeat_ms,
                 force_heartbeat_ms=args.force_heartbeat_ms, contact=not args.no_contact,
                 exact=args.exact)
    if sized.buses is None:
        raise ConfigError("--max-load", f"one patch alone is above {args.max_load:g} % of a "
                                        f"bus at {args.rate:g} Hz: lower the rate"
                                        f"{'' if args.fd else ' or use --fd'}")
    return sized.buses


def _plan(args: argparse.Namespace) -> int:
    from canbus.busload import plan
    from skin.atomic import atomic_write

    _check(args)
    if args.buses is None:
        args.buses = 1 if args.max_load is None else _buses_under_max_load(args)
    data_bitrate = args.data_bitrate if args.fd else None
    result = plan(args.patches, args.rate, args.mode, args.bitrate,
                  data_bitrate=data_bitrate, target_pct=args.target, forces=args.forces,
                  buses=args.buses, heartbeat_ms=args.heartbeat_ms,
                  force_heartbeat_ms=args.force_heartbeat_ms, contact=not args.no_contact,
                  exact=args.exact)
    _print_plan(args, result)
    sizings = _sizings(args)
    _print_sizing(args, sizings)
    if args.json:
        record = _record(result) | {"sizing": {("fd" if s.fd else "classic"): asdict(s)
                                               for s in sizings}}
        with atomic_write(args.json) as handle:
            handle.write(json.dumps(record, indent=2).encode() + b"\n")
    _warn_if_over(result, sizings)
    return 0


def _print_plan(args: argparse.Namespace, result: Plan) -> None:
    """The settings, then each bus (one bus) or the split over the buses (several)."""
    bus = (f"CAN FD {args.bitrate}/{result.data_bitrate} bit/s" if result.data_bitrate
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
    if len(result.buses) == 1:
        print("\n".join(_describe_bus(result.buses[0], result)))
        return
    _print_split(result)
    print(f"worst bus: {result.worst_bus}, {result.load_worst_pct:.1f} % worst case")


def _warn_if_over(result: Plan, sizings: list[Sizing]) -> None:
    advice = _advice(sizings)
    if not result.fits:
        warn(f"warning: the traffic does not fit: {result.worst_bus} needs "
             f"{result.load_best_pct:.1f} to {result.load_worst_pct:.1f} % of its wire; "
             f"{_lower_rate(result)}{advice}")
    elif result.over_target:
        warn(f"warning: worst-case load {result.load_worst_pct:.1f} % is above the "
             f"{result.target_pct:g} % target; {_lower_rate(result)}{advice}")


def _lower_rate(result: Plan) -> str:
    """The rate that fits, or why none does (the heartbeats alone fill the bus)."""
    if result.max_rate_hz < 0.05:
        return (f"no sample rate fits {result.worst_bus} (its heartbeats alone are over the "
                f"{result.target_pct:g} % target)")
    return f"lower the rate to {result.max_rate_hz:,.1f} Hz"


def _same_split(a: BusPlan, b: BusPlan) -> bool:
    return (a.name == "forces") == (b.name == "forces") and \
        (len(a.patches), len(a.force_nodes)) == (len(b.patches), len(b.force_nodes))


def _print_split(result: Plan) -> None:
    """One row per run of buses that carry as many nodes (so as much load) as each other."""
    from skin.commands.common.tables import show

    runs: list[list[BusPlan]] = []
    for bus in result.buses:
        if runs and _same_split(runs[-1][0], bus):
            runs[-1].append(bus)
        else:
            runs.append([bus])
    rows = [_split_row(run) for run in runs]
    show(f"the split over {len(result.buses)} buses (each bus of a row alike)",
         ["buses", "patches", "per bus", "frames/s a bus", "load a bus", "worst-case latency"],
         rows, caption="load: no stuffing .. worst-case stuffing; latency: from a SYNC due to "
         "the last frame of its cycle on the wire (docs/canbus.md)")


def _split_row(run: list[BusPlan]) -> list[str]:
    first, last = run[0], run[-1]
    names = first.name if len(run) == 1 else f"{first.name}..{last.name.split()[-1]}"
    ids = first.patches + last.patches or first.force_nodes + last.force_nodes
    nodes = f"{ids[0]}-{ids[-1]}" if ids else "none"
    per_bus = len(first.patches) or len(first.force_nodes)
    latency = "unbounded" if first.latency_ms_worst is None else \
        f"{first.latency_ms_worst:.2f} ms"
    return [names, nodes if first.patches else f"force nodes {nodes}", f"{per_bus}",
            f"{sum(first.frames_per_s.values()):,.0f}",
            f"{first.load_best_pct:.1f} .. {first.load_worst_pct:.1f} %", latency]


def _sizings(args: argparse.Namespace) -> list[Sizing]:
    """The buses needed at the target, classic CAN and CAN FD (``canbus.sizing``)."""
    from canbus.sizing import size

    return [size(args.patches, args.rate, args.mode, args.bitrate, data_bitrate=fd,
                 target_pct=args.target, forces=args.forces, heartbeat_ms=args.heartbeat_ms,
                 force_heartbeat_ms=args.force_heartbeat_ms, contact=not args.no_contact,
                 exact=args.exact)
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
    split = parser.add_mutually_exclusive_group()
    split.add_argument("--buses", type=argtypes.count("buses", 1, 100_000), metavar="N",
                       help="spread the patches over N buses, each with its own SYNC "
                            "(default 1)")
    split.add_argument("--max-load", type=argtypes.percent, metavar="PCT",
                       help="as many buses as keep each one's worst-case load at most PCT "
                            "%%, the fewest")
    parser.add_argument("--heartbeat-ms", type=argtypes.heartbeat_ms, default=100, metavar="MS",
                        help="patch heartbeat period (default 100; 0 = off)")
    parser.add_argument("--force-heartbeat-ms", type=argtypes.heartbeat_ms, default=1000,
                        metavar="MS",
                        help="force node heartbeat period (default 1000; 0 = off)")
    parser.add_argument("--target", type=argtypes.percent, default=70.0, metavar="PCT",
                        help="target bus load in %% (default 70)")
    parser.add_argument("--exact", action="store_true",
                        help="list and sum every frame of every bus, and try 1, 2, ... buses "
                             "for the buses needed (slow: the square of the patches); the "
                             "default adds up one node's share")
    parser.add_argument("--json", type=argtypes.output_file, metavar="FILE",
                        help="also write the figures as JSON")
    parser.set_defaults(func=_plan)
