"""What a ``skin demo`` run adds up to: its buses, the summary record (``--json``) from the
host's counters and the bus clocks' measurements, and the summary's lines."""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import can
    import canopen

    from canbus.busload import Plan
    from canbus.device.patch_server import PatchServer
    from sim import Scene
    from skin.commands.demo.rig import BusClock, Record


@dataclass
class DemoBus:
    """One bus of the demo: its name, patches, the host's end and the patches' end."""

    name: str
    patches: tuple[int, ...]
    host_bus: can.BusABC
    network: canopen.Network
    server: PatchServer
    clock: BusClock
    wire_start: Any = None
    wire_end: Any = None
    frames_sent: int = 0


def summary(args: argparse.Namespace, scene: Scene, plan: Plan, opened: list[DemoBus],
             live: Record, stats: dict[str, int], seconds: float, truth: Any, known: Any,
             cpus: set[int] | None) -> dict[str, Any]:
    import numpy as np

    from skin.commands.demo.rig import percentiles

    cycle = np.concatenate([live.cycle_latencies_ms(b.clock, list(b.patches)) for b in opened])
    sample = np.concatenate([live.sample_latencies_ms(b.clock, list(b.patches))
                             for b in opened])
    wire = np.concatenate([b.clock.wire_ms() for b in opened])
    used = stats["frames_in"] - stats["late_frames"] - stats["duplicate_frames"] - \
        stats["out_of_order_frames"] - stats["malformed_frames"]
    seen = sum(b.clock.force_frames for b in opened)
    dropped = (sum(b.frames_sent for b in opened) - used) + (stats["frames_out"] - seen) + \
        stats["send_errors"]
    loads = [round(b.wire_end.load_since(b.wire_start), 2)
             if b.wire_start is not None and b.wire_end is not None else None for b in opened]
    p50, p99, worst = percentiles(cycle, [50, 99, 100])
    s50, s99, smax = percentiles(sample, [50, 99, 100])
    w50, w99 = percentiles(wire, [50, 99])
    measured = [x for x in loads if x is not None]
    rates = [(len(b.clock.syncs) - 1) / (b.clock.syncs[-1] - b.clock.syncs[0])
             for b in opened if len(b.clock.syncs) > 1 and b.clock.syncs[-1] > b.clock.syncs[0]]
    return {
        "bus": args.bus, "bitrate": args.bitrate if args.bus == "timed" else None,
        "data_bitrate": args.data_bitrate if args.fd else None, "fd": args.fd,
        "buses": len(opened), "patches": len(scene.node_ids), "seconds": round(seconds, 3),
        "scene": scene.name, "mode": scene.mode, "rate_hz": scene.rate_hz,
        "samples": stats["samples"], "complete_samples": stats["complete_samples"],
        "incomplete_samples": stats["incomplete_samples"], "dropped_frames": dropped,
        "samples_per_s": round(stats["samples"] / seconds, 1),
        "sync_hz": round(min(rates), 2) if rates else None,
        "bus_load_pct": max(measured) if measured else None,
        "bus_loads_pct": {b.name: load for b, load in zip(opened, loads, strict=True)},
        "plan": {"load_pct": {"best": round(plan.load_best_pct, 2),
                              "worst": round(plan.load_worst_pct, 2)},
                 "cycle_ms": {"best": round(plan.cycle_ms_best, 3),
                              "worst": round(plan.cycle_ms_worst, 3)},
                 "buses": {name: {"best": round(b.load_best_pct, 2),
                                  "worst": round(b.load_worst_pct, 2)}
                           for name, b in zip([o.name for o in opened], plan.buses,
                                              strict=False)}},
        "wire_ms": {"p50": _figure(w50), "p99": _figure(w99)},
        "latency_ms": {"p50": _figure(p50), "p99": _figure(p99), "max": _figure(worst)},
        "sample_latency_ms": {"p50": _figure(s50), "p99": _figure(s99), "max": _figure(smax)},
        "rmse_N": _figure(live.rmse_N(truth, known), 5),
        "decoder": "analytic",
        "sync_overruns": stats["sync_overruns"],
        "cpus": None if cpus is None else sorted(cpus),
    }


def print_summary(record: dict[str, Any]) -> None:
    print(f"  samples   {record['samples']} ({record['complete_samples']} complete, "
          f"{record['incomplete_samples']} incomplete) in {record['seconds']:.1f} s = "
          f"{record['samples_per_s']:g}/s; dropped frames {record['dropped_frames']}")
    latency, wire = record["latency_ms"], record["wire_ms"]
    line = (f"  latency   SYNC -> the cycle's last force PDO: p50 {_ms(latency['p50'])}, "
            f"p99 {_ms(latency['p99'])}")
    if wire["p50"] is not None:
        line += f"; the cycle's frames hold the wire {_ms(wire['p50'])} (p50)"
    print(line)
    if record["bus_load_pct"] is not None:
        plan = record["plan"]["load_pct"]
        print(f"  bus load  {record['bus_load_pct']:.1f} % measured (plan: {plan['best']:.1f}-"
              f"{plan['worst']:.1f} %)")
    print(f"  accuracy  rmse {record['rmse_N']:.4f} N against the simulator's true forces")


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f} ms"


def _figure(value: float, digits: int = 3) -> float | None:
    """A rounded figure for JSON; None (null) where there is none."""
    return None if math.isnan(value) else round(value, digits)
