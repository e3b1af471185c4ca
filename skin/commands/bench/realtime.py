"""``skin bench realtime``: the host beside CPU-bound processes, with and without
``--realtime`` (:mod:`skin.benchmarks.realtime`); the command line and the printed figures."""

from __future__ import annotations

import argparse
from typing import Any

from skin.commands.common import argtypes


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("realtime", "skin bench realtime (--patches, --seconds "
                                                  "as above; defaults 8 and 20)")
    group.add_argument("--hogs", type=argtypes.count("hogs", 0, 64), default=None, metavar="K",
                       help="CPU-bound processes beside the host (default 2)")


def run_realtime(args: argparse.Namespace) -> dict[str, Any]:
    from skin.benchmarks.realtime import (
        DEFAULT_HOGS,
        DEFAULT_PATCHES,
        DEFAULT_SECONDS,
        run_realtime_benchmark,
    )

    patches = args.patches if args.patches is not None else DEFAULT_PATCHES
    hogs = args.hogs if args.hogs is not None else DEFAULT_HOGS
    seconds = args.seconds if args.seconds is not None else \
        (5.0 if args.quick else DEFAULT_SECONDS)
    result = run_realtime_benchmark(patches, hogs, seconds)
    print_realtime(result)
    return result


def print_realtime(r: dict[str, Any]) -> None:
    from skin.commands.common.tables import show

    rows = []
    for run in r["runs"]:
        win, lat = run["incomplete_pct_per_window"], run["sync_to_last_force_pdo_ms"]
        own = run["last_patch_pdo_to_last_force_pdo_ms"]
        rt = "realtime" if run["host_realtime"] else \
            ("realtime (not granted)" if run["realtime"] else "normal")
        rows.append([rt, _pct(run["complete_pct"]), f"{_num(win['max'])} / {_num(win['p95'])}",
                     f"{_num(lat['p50'])} / {_num(lat['p99'])}",
                     f"{_num(own['p50'])} / {_num(own['p99'])}", f"{run['host_cpu_pct']:.1f} %",
                     f"{run['host_cpu_us_per_frame']:.1f}",
                     f"{run['bare_pycan_recv_cpu_us_per_frame']:.1f}",
                     f"{_num(run['host_over_bare'])}x"])
    rates = ", ".join(f"{run['frames_per_s']:,.0f}" for run in r["runs"])
    sim = "SCHED_FIFO 60" if all(run["sim_realtime"] for run in r["runs"]) else "normal priority"
    show(f"{r['patches']} patches (3-axis, 100 Hz) on udp_multicast, {r['hogs']} CPU-bound "
         f"process(es) beside the host, {r['seconds']:g} s windows",
         ["host", "complete (steady)", "incomplete per 2 s: max / p95 %",
          "SYNC -> last force PDO p50 / p99 ms", "last patch PDO -> last force PDO",
          "host CPU", "host us/frame",
          "bare python-can us/frame", "host / bare"], rows,
         caption=f"patches at {sim}; frames per second on the bus {rates}; "
                 f"{r['cpu_count']} CPUs")


def _pct(value: float | None) -> str:
    return "none" if value is None else f"{value:.3f} %"


def _num(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"
