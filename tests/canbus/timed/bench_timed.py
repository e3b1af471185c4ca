"""Benchmark: CPU per frame of the timed bus against python-can's virtual bus, same traffic.

    python tests/canbus/timed/bench_timed.py [--seconds 5] [--json F]

Per channel three buses, as in ``skin demo``: the patches' bus sends their TPDOs, the host's
bus sends SYNC and the force PDOs, a listener timestamps everything; each bus reads what the
others send in its own thread (as a Notifier would). Every 10 ms a sender thread puts one
cycle on every channel. Scenarios:

- ``demo4``: 4 patches x 7 TPDOs + SYNC + 4 x 7 force PDOs, 8-byte frames, one channel
  (5,700 frames/s, 62-76 % of 1 Mbit/s);
- ``demo4x2``: the same on two channels (11,400 frames/s, two wires, two threads);
- ``short15k``: 150 1-byte frames per cycle on one channel (15,000 frames/s, about 90 % of
  1 Mbit/s): the wire at its busiest.

Reported per interface: process CPU per frame sent (all threads: sender, readers, wire),
frames received, and for the timed bus the wire thread's own CPU share and how late frames
reach their readers after their timestamp (the end of their EOF on the wire's clock).
Machines differ: compare timed with virtual in the same run.
"""

from __future__ import annotations

import argparse
import json
import statistics
import threading
import time
from dataclasses import asdict, dataclass

import can

from canbus.timed.channels import wire_of

CYCLE_S = 0.01


@dataclass
class Result:
    scenario: str
    interface: str
    frames_per_s_offered: float
    frames_sent: int
    frames_received: int
    cpu_us_per_frame: float
    wire_thread_cpu_pct: float | None
    lag_ms_p50: float
    lag_ms_p99: float
    lag_ms_max: float
    load_pct: float | None


def _cycle(patches: int, short: int) -> list[tuple[str, int, bytes]]:
    """(sender, COB-ID, payload) of one cycle."""
    if short:
        return [("host", 0x080, b"\x01")] + [("patches", 0x181 + k % 100, b"\x55")
                                            for k in range(short - 1)]
    frames = [("host", 0x080, b"\x01")]
    bases = (0x180, 0x280, 0x380, 0x480, 0x200, 0x300, 0x400)
    frames += [("patches", base + node, bytes(range(node, node + 8)))
               for node in range(1, patches + 1) for base in bases]
    frames += [("host", base + node + 64, bytes(range(node, node + 8)))
               for node in range(1, patches + 1) for base in bases]
    return frames


def _thread_cpu(thread: threading.Thread | None) -> float:
    if thread is None or thread.ident is None:
        return 0.0
    return time.clock_gettime(time.pthread_getcpuclockid(thread.ident))


def run(scenario: str, interface: str, channels: int, patches: int, short: int,
        seconds: float, resolution_s: float | None) -> Result:
    kwargs: dict[str, float] = {}
    if interface == "timed":
        kwargs["bitrate"] = 1_000_000
        if resolution_s is not None:
            kwargs["resolution_s"] = resolution_s
    names = [f"bench-{scenario}-{interface}-{k}" for k in range(channels)]
    buses = [{role: can.Bus(interface=interface, channel=name, **kwargs)
              for role in ("patches", "host", "listener")} for name in names]
    stop = threading.Event()
    lags: list[float] = []
    received = [0]
    lock = threading.Lock()

    def read(bus: can.BusABC, timed: bool) -> None:
        mine: list[float] = []
        count = 0
        while not stop.is_set():
            msg = bus.recv(0.05)
            if msg is None:
                continue
            count += 1
            if timed:
                mine.append(time.time() - msg.timestamp)
        with lock:
            received[0] += count
            lags.extend(mine)

    readers = [threading.Thread(target=read, args=(bus, role == "listener"))
               for group in buses for role, bus in group.items()]
    for reader in readers:
        reader.start()
    cycle = _cycle(patches, short)
    messages = [[(group[role], can.Message(arbitration_id=cob, data=data, is_extended_id=False))
                 for role, cob, data in cycle] for group in buses]
    wires = [wire_of(name) for name in names] if interface == "timed" else []
    wire_cpu0 = [_thread_cpu(w.thread) for w in wires if w is not None]
    stats0 = [group["listener"].wire_stats() for group in buses] if interface == "timed" else []
    cycles = round(seconds / CYCLE_S)
    cpu0, start = time.process_time(), time.perf_counter()
    for k in range(cycles):
        for channel in messages:
            for bus, msg in channel:
                bus.send(msg)
        pause = start + (k + 1) * CYCLE_S - time.perf_counter()
        if pause > 0:
            time.sleep(pause)
    time.sleep(0.1)  # the last cycle's frames cross the wire
    elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu0
    wire_cpu = sum(_thread_cpu(w.thread) for w in wires if w is not None) - sum(wire_cpu0)
    loads = [group["listener"].wire_stats().load_since(s0)
             for group, s0 in zip(buses, stats0, strict=True)] if stats0 else []
    stop.set()
    for reader in readers:
        reader.join()
    for group in buses:
        for bus in group.values():
            bus.shutdown()
    sent = cycles * len(cycle) * channels
    lags_ms = sorted(1e3 * x for x in lags) or [0.0]
    return Result(
        scenario=scenario, interface=interface,
        frames_per_s_offered=len(cycle) * channels / CYCLE_S, frames_sent=sent,
        frames_received=received[0], cpu_us_per_frame=1e6 * cpu / sent,
        wire_thread_cpu_pct=100 * wire_cpu / elapsed if wires else None,
        lag_ms_p50=statistics.median(lags_ms),
        lag_ms_p99=lags_ms[min(len(lags_ms) - 1, int(0.99 * len(lags_ms)))],
        lag_ms_max=lags_ms[-1], load_pct=max(loads) if loads else None)


SCENARIOS = {"demo4": (1, 4, 0), "demo4x2": (2, 4, 0), "short15k": (1, 0, 150)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--resolution", type=float, default=None, metavar="S",
                        help="the timed bus's resolution_s (default: its default)")
    parser.add_argument("--json", metavar="FILE")
    args = parser.parse_args()
    results = []
    for name, (channels, patches, short) in SCENARIOS.items():
        for interface in ("virtual", "timed"):
            result = run(name, interface, channels, patches, short, args.seconds,
                         args.resolution)
            results.append(result)
            wire = (f", wire thread {result.wire_thread_cpu_pct:.1f} % of a core, load "
                    f"{result.load_pct:.1f} %, lag p50 {result.lag_ms_p50:.2f} / p99 "
                    f"{result.lag_ms_p99:.2f} / max {result.lag_ms_max:.2f} ms"
                    if result.interface == "timed" else "")
            print(f"{name:9s} {interface:8s} {result.frames_per_s_offered:8,.0f} frames/s: "
                  f"{result.cpu_us_per_frame:5.1f} us CPU per frame (process), "
                  f"{result.frames_received:,} of {2 * result.frames_sent:,} "
                  f"deliveries{wire}", flush=True)
    for name in SCENARIOS:
        virtual, timed = (r for r in results if r.scenario == name)
        print(f"{name}: timed / virtual CPU per frame = "
              f"{timed.cpu_us_per_frame / virtual.cpu_us_per_frame:.2f}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as handle:
            json.dump([asdict(r) for r in results], handle, indent=2)


if __name__ == "__main__":
    main()
