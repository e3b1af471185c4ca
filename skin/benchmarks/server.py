"""``skin bench server``: the patch server's CPU per frame beside python-can's own ``send`` of
the same frames on the same bus, measured in one run, and the SYNC-to-last-TPDO time.

The server (this process) serves N patches from a source that runs on its own clock; a
master in another process (:func:`_master`, started with multiprocessing's ``spawn``) starts
the nodes by NMT, sends SYNC (with its counter) at the rate, and reads every frame with its
kernel receive time. Each round has two phases of the same length on the same bus:

* **serve**: the server answers every SYNC; CPU = ``time.process_time()`` of this process
  (every thread: the bus's receive thread, the sample thread with the simulator, heartbeats)
  over the phase, per TPDO sent; the source's own share (the simulator's steps) is kept
  apart too (``source_us_per_frame``, part of ``cpu_us_per_frame``);
* **send**: the server stopped, the very messages of one of its answers are sent again with
  the bus's own ``send`` at the same rate, with the same receive side in place (the
  notifier running, the same own frames dropped), per frame.

The master checks every answer: each SYNC's frames, in the order they arrived, must be every
patch's TPDOs once, in COB-ID order, patches in node-ID order; ``answer_ms`` is from the
SYNC's receive time to the answer's last TPDO's, both stamped by the master's kernel.
``patches_per_core_at_100hz`` is one core's second over what a patch costs per second at
100 Hz (7 TPDOs per SYNC at the serve phase's CPU per frame): a linear scale, since the
work of a SYNC (the sample, the packing, the sends) is per patch too.
"""

from __future__ import annotations

import gc
import math
import multiprocessing as mp
import os
import statistics
import threading
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any

import can
import canopen
import numpy as np

from canbus.busload import TPDO_BASES
from canbus.device.patch_server import PatchServer
from canbus.device.source import ResistanceSource
from canbus.frametime import patch_payloads
from canbus.rxfilter import receive_filter

SYNC_COB_ID = 0x080
PERIOD_S = 0.01
_SETTLE_S, _DRAIN_S = 0.3, 0.1


def default_port() -> int:
    """A UDP port of this process's own (udp_multicast sockets on one port hear every group)."""
    return 30000 + os.getpid() % 2000


def run_server_benchmark(make_source: Callable[[], ResistanceSource], *, channel: str,
                         port: int, seconds: float = 3.0, rounds: int = 3,
                         rate_hz: float = 100.0) -> dict[str, Any]:
    """Serve ``make_source()``'s patches on udp_multicast ``channel``:``port``; the figures."""
    source = make_source()
    patches = len(source.node_ids)
    cycles = max(1, round(seconds * rate_hz))
    ctx = mp.get_context("spawn")
    ours, theirs = ctx.Pipe()
    master = ctx.Process(target=_master, args=(theirs, channel, port, 1.0 / rate_hz),
                         daemon=True)
    master.start()
    load_before = os.getloadavg()
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.05
    network.connect(interface="udp_multicast", channel=channel, port=port)
    try:
        ours.recv()  # the master is on the bus
        results = [_round(network, source, ours, cycles) for _ in range(rounds)]
    finally:
        ours.send(("stop",))
        master.join(timeout=10)
        if master.is_alive():
            master.kill()
        network.disconnect()
    return _summary(results, patches, rate_hz, seconds, channel, port, load_before)


class _TimedSource:
    """A source that keeps the CPU time of its reads (the simulator's share)."""

    def __init__(self, source: ResistanceSource) -> None:
        self.source = source
        self.node_ids = source.node_ids
        self.pillars = source.pillars
        self.cpu_s = 0.0

    def read(self) -> np.ndarray:
        start = time.thread_time()
        sample = self.source.read()
        self.cpu_s += time.thread_time() - start
        return sample


def _round(network: canopen.Network, source: ResistanceSource, master: Connection,
           cycles: int) -> dict[str, Any]:
    timed = _TimedSource(source)
    server = PatchServer(network, timed, event_rate_hz=1.0 / PERIOD_S,
                         accept_only_consumed=True)
    gc.collect()  # as skin sim run: the object dictionaries out of the collector's way
    gc.freeze()
    server.start()
    try:
        master.send(("start",))
        master.recv()
        sent0, cpu0, wall0 = server.frames_sent, time.process_time(), time.monotonic()
        source0 = timed.cpu_s
        master.send(("serve", cycles, expected_answer(server)))
        checked = master.recv()
        cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
        source_cpu = timed.cpu_s - source0
        sent = server.frames_sent - sent0
        answer = server.answer()
        owned = {c for node in server.nodes for c in node.transmitted_cob_ids()}
    finally:
        server.stop()
        gc.unfreeze()
    bus = network.bus
    assert bus is not None
    own, sender = receive_filter(bus), object()
    own.claim(sender, owned)  # the receive side as while serving
    try:
        send_cpu, send_frames = _send_phase(bus, answer, cycles)
    finally:
        own.release(sender)
    return {"cpu_s": cpu, "wall_s": wall, "frames_sent": sent, "source_cpu_s": source_cpu,
            "send_cpu_s": send_cpu,
            "send_frames": send_frames, "syncs": server.sync_count, **checked}


def expected_answer(server: PatchServer) -> list[int]:
    """The COB-IDs of a whole answer: each patch's predefined TPDOs in ascending COB-ID
    order, the patches in node-ID order."""
    count = len(patch_payloads(server.nodes[0].mode, fd=False))
    return [base + n for n in sorted(node.node_id for node in server.nodes)
            for base in sorted(TPDO_BASES[:count])]


def _send_phase(bus: can.BusABC, answer: list[can.Message], cycles: int) -> tuple[float, int]:
    """python-can's ``send`` of ``answer`` once per period, ``cycles`` times: CPU, frames."""
    send = bus.send
    cpu0 = time.process_time()
    deadline = time.monotonic()
    for _ in range(cycles):
        deadline += PERIOD_S
        for msg in answer:
            send(msg)
        time.sleep(max(0.0, deadline - time.monotonic()))
    time.sleep(_DRAIN_S)
    return time.process_time() - cpu0, cycles * len(answer)


def _summary(results: list[dict[str, Any]], patches: int, rate_hz: float, seconds: float,
             channel: str, port: int, load_before: tuple[float, float, float]
             ) -> dict[str, Any]:
    rounds = []
    for r in results:
        cpu_us = 1e6 * r["cpu_s"] / max(r["frames_sent"], 1)
        send_us = 1e6 * r["send_cpu_s"] / max(r["send_frames"], 1)
        share = r["cpu_s"] / r["wall_s"]
        rounds.append({"cpu_us_per_frame": cpu_us, "send_us_per_frame": send_us,
                       "source_us_per_frame": 1e6 * r["source_cpu_s"] / max(r["frames_sent"], 1),
                       "ratio": cpu_us / send_us if send_us else math.inf,
                       "cpu_share": share, "frames_sent": r["frames_sent"],
                       "syncs": r["syncs"], "answers_complete": r["complete"],
                       "answers_checked": r["checked"]})
    latencies = np.concatenate([np.asarray(r["latency_ms"], dtype=np.float64)
                                for r in results])
    p50, p99 = (np.percentile(latencies, [50, 99]).tolist() if latencies.size
                else [math.nan, math.nan])
    share = statistics.median(r["cpu_share"] for r in rounds)
    return {
        "interface": "udp_multicast", "channel": channel, "port": port,
        "patches": patches, "mode": "xyz", "rate_hz": rate_hz, "rounds": len(rounds),
        "seconds_per_phase": seconds,
        "cpu_us_per_frame": statistics.median(r["cpu_us_per_frame"] for r in rounds),
        "send_us_per_frame": statistics.median(r["send_us_per_frame"] for r in rounds),
        "ratio": statistics.median(r["ratio"] for r in rounds),
        "source_us_per_frame": statistics.median(r["source_us_per_frame"] for r in rounds),
        "answer_ms": {"p50": p50, "p99": p99,
                      "max": float(latencies.max()) if latencies.size else math.nan},
        "patches_per_core_at_100hz": 1e6 / (statistics.median(r["cpu_us_per_frame"]
                                                              for r in rounds) * 7 * 100.0),
        "cpu_share": share,
        "answers_complete": sum(r["answers_complete"] for r in rounds),
        "answers_checked": sum(r["answers_checked"] for r in rounds),
        "frames_sent": sum(r["frames_sent"] for r in rounds),
        "load_average": {"before": list(load_before), "after": list(os.getloadavg())},
        "per_round": rounds,
    }


# --- the master (another process) --------------------------------------------------------

def _master(pipe: Connection, channel: str, port: int, period_s: float) -> None:
    """Start the nodes, SYNC, and check the answers, as told through ``pipe``."""
    bus = can.Bus(interface="udp_multicast", channel=channel, port=port)
    frames: list[tuple[float, int]] = []
    reading = threading.Event()
    reading.set()

    def read() -> None:
        while reading.is_set():
            msg = bus.recv(0.05)
            if msg is not None and not msg.is_extended_id:
                frames.append((msg.timestamp, msg.arbitration_id))

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    pipe.send("ready")
    try:
        while True:
            command = pipe.recv()
            if command[0] == "stop":
                break
            if command[0] == "start":
                time.sleep(_SETTLE_S)  # the nodes have booted
                bus.send(can.Message(arbitration_id=0, data=[1, 0], is_extended_id=False))
                time.sleep(_SETTLE_S)
                pipe.send("started")
            elif command[0] == "serve":
                frames.clear()
                _sync(bus, command[1], period_s)
                time.sleep(_DRAIN_S)
                pipe.send(check_answers(list(frames), command[2]))
    finally:
        reading.clear()
        reader.join()
        bus.shutdown()


def _sync(bus: can.BusABC, cycles: int, period_s: float) -> None:
    deadline = time.monotonic()
    for k in range(cycles):
        deadline += period_s
        bus.send(can.Message(arbitration_id=SYNC_COB_ID, data=[k % 240 + 1],
                             is_extended_id=False))
        time.sleep(max(0.0, deadline - time.monotonic()))


def check_answers(frames: list[tuple[float, int]], expected: list[int]) -> dict[str, Any]:
    """Split ``(time, COB-ID)`` frames at each SYNC: how many answers are exactly
    ``expected`` (every TPDO once, in that order), and each answer's time from its SYNC to
    its last TPDO in ms."""
    answers: list[tuple[float, list[tuple[float, int]]]] = []
    for at, cob_id in frames:
        if cob_id == SYNC_COB_ID:
            answers.append((at, []))
        elif answers and 0x180 <= cob_id < 0x500:
            answers[-1][1].append((at, cob_id))
    complete = sum(1 for _, got in answers if [c for _, c in got] == expected)
    latency = [1e3 * (got[-1][0] - sync) for sync, got in answers if got]
    return {"checked": len(answers), "complete": complete, "latency_ms": latency}
