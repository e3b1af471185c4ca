"""Benchmark: CPU per frame of the timed bus against python-can's virtual bus, same traffic.

    python -m tests.support.timed [--seconds 5] [--runs 1] [--json F]

Traffic as in ``skin demo``, cause and effect included. Per channel two buses, each read by a
``can.Notifier`` (as canopen reads its network): the host's bus and the patches' bus. A SYNC
thread sends SYNC on the host's bus every 10 ms; the patches' listener answers each SYNC
with 7 TPDOs per patch; the host's listener hands each patch's TPDOs, once all 7 are in, to a
publisher thread, which sends that patch's 7 force PDOs on the host's bus. Every payload is
new (8 random bytes, as sensor readings are), so nothing can be cached by content.
Scenarios:

- ``demo4``: 4 patches, one channel: 57 frames per cycle, 5,700 frames/s, about 66 % of
  1 Mbit/s;
- ``demo4x2``: the same on two channels (``skin demo --patches 8 --buses 2``);
- ``short15k``: the patches answer each SYNC with 149 1-byte frames (15,000 frames/s, about
  83 % of 1 Mbit/s), nothing published: the wire at its busiest.

Reported per interface: the process's CPU per frame sent (all threads: SYNC, listeners,
publisher), its context switches per frame (each a thread woken: what costs most), frames
delivered, cycles whose TPDOs did not all reach the host before the next SYNC (``late``),
the latency from SYNC to the cycle's last force PDO by their timestamps; for the timed bus
also the measured load.
Machines differ and this one is shared: compare timed with virtual in the same run (the
runs alternate between them) and look at the spread over ``--runs``.

``--bits`` times the frame-bit count instead (``canbus.framebits``): an 8-byte classic frame
with new content each call and with the same content again, a 64-byte CAN FD frame, against
building a ``can.Message`` in the same run.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import resource
import statistics
import threading
import time
import timeit
from dataclasses import asdict, dataclass, field
from typing import Any

import can

CYCLE_S = 0.01
TPDO_BASES = (0x180, 0x280, 0x380, 0x480, 0x200, 0x300, 0x400)
FORCE_NODE = 64  # a patch's forces go out as node-ID + 64


@dataclass
class Result:
    scenario: str
    interface: str
    frames_per_s_offered: float
    frames_sent: int
    frames_received: int
    cpu_us_per_frame: float
    late_cycles: int
    cycles: int
    latency_ms_p50: float
    latency_ms_p99: float
    switches_per_frame: float
    """Context switches of the process (every thread) per frame sent."""
    load_pct: float | None
    load_average: float


@dataclass
class _Channel:
    """One channel's buses, notifiers and what they saw."""

    host: can.BusABC
    patches: can.BusABC
    rng: random.Random
    sync_at: dict[int, float] = field(default_factory=dict)
    """Cycle -> timestamp of its SYNC, as the patches received it."""
    tpdos: dict[int, int] = field(default_factory=dict)
    """Cycle -> TPDOs the host received for it."""
    last_force: dict[int, float] = field(default_factory=dict)
    """Cycle -> timestamp of its last force PDO seen on the patches' side."""
    late: int = 0
    received: int = 0
    sent: int = 0


def _frame(can_id: int, data: bytes) -> can.Message:
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=False)


class _Patches(can.Listener):
    """The simulated patches: each SYNC answered with every patch's TPDOs."""

    def __init__(self, ch: _Channel, patches: int, short: int) -> None:
        self.ch, self.short = ch, short
        self.cobs = [base + node for node in range(1, patches + 1) for base in TPDO_BASES]

    def on_message_received(self, msg: can.Message) -> None:
        ch = self.ch
        ch.received += 1
        if msg.arbitration_id == 0x080:
            cycle = int.from_bytes(msg.data, "little")
            ch.sync_at[cycle] = msg.timestamp
            randbytes, send = ch.rng.randbytes, ch.patches.send
            if self.short:
                for k in range(self.short):
                    send(_frame(0x181 + k % 100, randbytes(1)))
                ch.sent += self.short
                return
            for cob in self.cobs:
                send(_frame(cob, bytes(msg.data) + randbytes(6)))
            ch.sent += len(self.cobs)
        elif msg.arbitration_id & 0x7F > FORCE_NODE:
            ch.last_force[int.from_bytes(msg.data[:2], "little")] = msg.timestamp


class _Host(can.Listener):
    """The host's side: counts each patch's TPDOs, hands a complete sample on."""

    def __init__(self, ch: _Channel, publish: list[tuple[_Channel, bytes, int]],
                 ready: threading.Condition, short: int) -> None:
        self.ch, self.publish, self.ready, self.short = ch, publish, ready, short
        self.seen: dict[tuple[bytes, int], int] = {}

    def on_message_received(self, msg: can.Message) -> None:
        ch = self.ch
        ch.received += 1
        if self.short:
            return
        cycle, node = bytes(msg.data[:2]), msg.arbitration_id & 0x7F
        number = int.from_bytes(cycle, "little")
        ch.tpdos[number] = ch.tpdos.get(number, 0) + 1
        key = (cycle, node)
        count = self.seen.get(key, 0) + 1
        if count < len(TPDO_BASES):
            self.seen[key] = count
            return
        self.seen.pop(key, None)
        with self.ready:
            self.publish.append((ch, cycle, node))
            self.ready.notify()


def _publisher(publish: list[tuple[_Channel, bytes, int]], ready: threading.Condition,
               stop: threading.Event) -> None:
    """Sends each complete sample's force PDOs (the data plane's publishing thread)."""
    while True:
        with ready:
            while not publish and not stop.is_set():
                ready.wait(0.05)
            if not publish:
                return
            jobs = publish[:]
            publish.clear()
        for ch, cycle, node in jobs:
            randbytes, send = ch.rng.randbytes, ch.host.send
            for base in TPDO_BASES:
                send(_frame(base + node + FORCE_NODE, cycle + randbytes(6)))
            ch.sent += len(TPDO_BASES)


def _sync(channels: list[_Channel], cycles: int, patches: int, short: int) -> None:
    """SYNC every 10 ms on every channel, absolute deadlines; counts late cycles."""
    start = time.monotonic()
    expected = short or patches * len(TPDO_BASES)
    for k in range(cycles):
        for ch in channels:
            if k and ch.tpdos.get(k - 1, 0) < expected and not short:
                ch.late += 1
            ch.host.send(_frame(0x080, k.to_bytes(2, "little")))
            ch.sent += 1
        pause = start + (k + 1) * CYCLE_S - time.monotonic()
        if pause > 0:
            time.sleep(pause)


def _switches() -> int:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_nvcsw + usage.ru_nivcsw


def run(scenario: str, interface: str, channels: int, patches: int, short: int,
        seconds: float) -> Result:
    kwargs: dict[str, Any] = {"bitrate": 1_000_000} if interface == "timed" else {}
    names = [f"bench-{scenario}-{interface}-{k}" for k in range(channels)]
    chans = [_Channel(can.Bus(interface=interface, channel=name, **kwargs),
                      can.Bus(interface=interface, channel=name, **kwargs),
                      random.Random(k)) for k, name in enumerate(names)]
    publish: list[tuple[_Channel, bytes, int]] = []
    ready, stop = threading.Condition(), threading.Event()
    notifiers = []
    for ch in chans:
        notifiers.append(can.Notifier(ch.patches, [_Patches(ch, patches, short)], timeout=0.05))
        notifiers.append(can.Notifier(ch.host, [_Host(ch, publish, ready, short)],
                                      timeout=0.05))
    publisher = threading.Thread(target=_publisher, args=(publish, ready, stop), daemon=True)
    publisher.start()
    stats0 = ([ch.host.wire_stats() for ch in chans]  # type: ignore[attr-defined]
              if interface == "timed" else [])
    cycles = round(seconds / CYCLE_S)
    cpu0, switches0 = time.process_time(), _switches()
    _sync(chans, cycles, patches, short)
    time.sleep(0.02)  # the last cycle's frames cross the wire
    cpu, switches = time.process_time() - cpu0, _switches() - switches0
    loads = [ch.host.wire_stats().load_since(s0)  # type: ignore[attr-defined]
             for ch, s0 in zip(chans, stats0, strict=False)]
    for notifier in notifiers:
        notifier.stop()
    stop.set()
    publisher.join()
    for ch in chans:
        ch.host.shutdown()
        ch.patches.shutdown()
    latencies = sorted(1e3 * (ch.last_force[c] - ch.sync_at[c]) for ch in chans
                       for c in ch.last_force if c in ch.sync_at) or [math.nan]
    sent = sum(ch.sent for ch in chans)
    return Result(
        scenario=scenario, interface=interface,
        frames_per_s_offered=(1 + (short or 2 * patches * len(TPDO_BASES))) * channels / CYCLE_S,
        frames_sent=sent, frames_received=sum(ch.received for ch in chans),
        cpu_us_per_frame=1e6 * cpu / max(sent, 1),
        late_cycles=sum(ch.late for ch in chans), cycles=cycles * channels,
        latency_ms_p50=statistics.median(latencies),
        latency_ms_p99=latencies[min(len(latencies) - 1, int(0.99 * len(latencies)))],
        switches_per_frame=switches / max(sent, 1),
        load_pct=max(loads) if loads else None, load_average=os.getloadavg()[0])


SCENARIOS = {"demo4": (1, 4, 0), "demo4x2": (2, 4, 0), "short15k": (1, 0, 149)}


def bits(repeat: int = 15, number: int = 20000) -> dict[str, float]:
    """Frame-bit counts in microseconds per call, interleaved, best of ``repeat``."""
    from canbus import framebits

    fresh = iter([os.urandom(8) for _ in range(2 * repeat * number)])
    fd = iter([os.urandom(64) for _ in range(repeat * number)])
    scope = {"frame_bits": framebits.frame_bits, "can": can, "fresh": fresh, "fd": fd,
             "same": bytes(range(8))}
    statements = {
        "8-byte classic frame, new content each call": "frame_bits(0x181, next(fresh))",
        "8-byte classic frame, the same content again": "frame_bits(0x181, same)",
        "64-byte CAN FD frame with BRS, new content": "frame_bits(0x181, next(fd), fd=True, "
                                                      "brs=True)",
        "can.Message(...) (the peer)": "can.Message(arbitration_id=0x181, data=same, "
                                       "is_extended_id=False)",
        "next(...) alone (the loop's overhead)": "next(fresh)",
    }
    framebits.frame_bits(0x181, bytes(8))  # the tables are built on first use
    best = dict.fromkeys(statements, math.inf)
    for _ in range(repeat):
        for name, statement in statements.items():
            best[name] = min(best[name], timeit.timeit(statement, globals=scope,
                                                       number=number) / number)
    return {name: 1e6 * t for name, t in best.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--runs", type=int, default=1, help="runs of every scenario")
    parser.add_argument("--scenario", choices=sorted(SCENARIOS), action="append",
                        help="only these scenarios (default all)")
    parser.add_argument("--bits", action="store_true", help="time the frame-bit count instead")
    parser.add_argument("--json", metavar="FILE")
    args = parser.parse_args()
    if args.bits:
        figures = bits()
        for name, us in figures.items():
            print(f"{us:6.2f} us  {name}")
        if args.json:
            with open(args.json, "w", encoding="utf-8") as handle:
                json.dump(figures, handle, indent=2)
        return
    can.Message()  # python-can's lazy imports, and the frame-bit tables, before any run
    from canbus.framebits import frame_bits

    frame_bits(0x181, bytes(8))
    results = []
    ratios: dict[str, list[float]] = {}
    for name in args.scenario or SCENARIOS:
        channels, patches, short = SCENARIOS[name]
        for k in range(args.runs):
            pair = {}
            for interface in ("virtual", "timed") if k % 2 == 0 else ("timed", "virtual"):
                r = pair[interface] = run(name, interface, channels, patches, short,
                                          args.seconds)
                results.append(r)
                wire = f", load {r.load_pct:.1f} %" if r.interface == "timed" else ""
                print(f"{name:9s} {interface:8s} {r.frames_sent / args.seconds:7,.0f} frames/s: "
                      f"{r.cpu_us_per_frame:5.1f} us CPU per frame, {r.frames_received:,} "
                      f"of {r.frames_sent:,} delivered, late cycles {r.late_cycles}/{r.cycles}, "
                      f"latency p50 {r.latency_ms_p50:.2f} p99 {r.latency_ms_p99:.2f} ms, "
                      f"{r.switches_per_frame:.2f} context switches per frame{wire} "
                      f"(load average {r.load_average:.2f})", flush=True)
            ratios.setdefault(name, []).append(
                pair["timed"].cpu_us_per_frame / pair["virtual"].cpu_us_per_frame)
    for name, values in ratios.items():
        print(f"{name}: timed / virtual CPU per frame = {', '.join(f'{v:.2f}' for v in values)}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as handle:
            json.dump([asdict(r) for r in results], handle, indent=2)


if __name__ == "__main__":
    main()
