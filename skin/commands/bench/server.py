"""``skin bench server``: the patch server against python-can's own ``send``, in one run."""

from __future__ import annotations

import argparse
from typing import Any

from skin.commands.common import argtypes

DEFAULT_PATCHES = 16
SCENE = "indenter"  # 3-axis, 100 Hz; here on every patch (every one loaded, none cached)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("server", "skin bench server (udp_multicast, another "
                                                "process as the master)")
    group.add_argument("--patches", type=argtypes.patches, default=None, metavar="N",
                       help=f"patches served, 3-axis at 100 Hz (default {DEFAULT_PATCHES}; "
                            "publish: 32)")
    group.add_argument("--seconds", type=argtypes.seconds, default=None, metavar="S",
                       help="length of each phase (default 3; --quick 1)")
    group.add_argument("--rounds", type=argtypes.count("rounds", 1, 1000), default=None,
                       metavar="R",
                       help="serve and send phases, alternating (default 3; --quick 1)")
    group.add_argument("--channel", default="239.74.163.254", metavar="GROUP",
                       help="the multicast group (default 239.74.163.254)")
    group.add_argument("--port", type=argtypes.port, default=None, metavar="PORT",
                       help="the UDP port (default: one of this process's own, 30000..31999)")


def run_server(args: argparse.Namespace) -> dict[str, Any]:
    from canbus.device.source import SimulatorSource
    from sim import Simulator
    from skin.benchmarks.server import default_port, run_server_benchmark
    from skin.commands.sim.run import AHEAD_S, scene_on_patches
    from skin.errors import ConfigError

    patches = args.patches if args.patches is not None else DEFAULT_PATCHES
    seconds = args.seconds if args.seconds is not None else (1.0 if args.quick else 3.0)
    rounds = args.rounds if args.rounds is not None else (1 if args.quick else 3)
    if not seconds > 0:
        raise ConfigError("--seconds", f"must be > 0, got {seconds}")
    if rounds < 1:
        raise ConfigError("--rounds", f"must be at least 1, got {rounds}")
    scene = scene_on_patches(SCENE, patches)
    ahead = max(1, round(AHEAD_S * scene.rate_hz))  # as skin sim run serves it
    return run_server_benchmark(lambda: SimulatorSource(Simulator(scene), ahead=ahead),
                                channel=args.channel, port=args.port or default_port(),
                                seconds=seconds, rounds=rounds, rate_hz=scene.rate_hz)


def print_server(result: dict[str, Any]) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console()
    rounds = result["per_round"]
    table = Table(title=f"patch server: {result['patches']} patches ({result['mode']}, "
                        f"{result['rate_hz']:g} Hz) on udp_multicast, master in another process",
                  caption=f"{result['rounds']} round(s) of {result['seconds_per_phase']:g} s "
                          "per phase; median (range)")
    for col in ("", "CPU per frame", "ratio"):
        table.add_column(col, justify="left" if not col else "right")

    def spread(key: str, digits: int = 1) -> str:
        values = [r[key] for r in rounds]
        return (f"{result[key]:.{digits}f} ({min(values):.{digits}f}-{max(values):.{digits}f})"
                if len(values) > 1 else f"{result[key]:.{digits}f}")

    table.add_row("patch server, per TPDO sent", f"{spread('cpu_us_per_frame')} us",
                  f"{spread('ratio', 2)}x")
    table.add_row("  of which the simulator (one run per 0.1 s)",
                  f"{spread('source_us_per_frame')} us", "")
    table.add_row("python-can send of the same frames", f"{spread('send_us_per_frame')} us",
                  "1.00x")
    console.print(table)
    answer = result["answer_ms"]
    console.print(f"SYNC to the answer's last TPDO (the master's receive times): p50 "
                  f"{answer['p50']:.2f} ms, p99 {answer['p99']:.2f} ms, max {answer['max']:.2f}"
                  f" ms; {result['answers_complete']:,} of {result['answers_checked']:,} answers "
                  "complete and in order")
    console.print(f"CPU share while serving {100 * result['cpu_share']:.0f} % of one core; "
                  f"{result['patches_per_core_at_100hz']:.0f} patches per core at 100 Hz (one "
                  "core's second over a patch's 700 TPDOs at the CPU per frame above); load "
                  f"average {result['load_average']['before'][0]:.1f} before, "
                  f"{result['load_average']['after'][0]:.1f} after")
