"""``skin demo``: simulated patches and the host manager on the embedded virtual bus.

The scene's patches (``--patches N``: node-IDs 1..N, every load of the scene on every
patch) run as CANopen nodes on their own canopen Network; the host discovers, configures
and starts them, sends SYNC at the scene's rate, decodes and publishes the forces. A
third bus on the same channel timestamps every SYNC and force TPDO, so latency is
measured on the bus: from a SYNC frame to the last force TPDO (TPDO 7) of each patch's
sample. The simulation is computed before the run and served one step per SYNC, so the
simulated patches answer at once and the truth of every cycle is known: ``rmse_N``
compares the published forces of the valid taxels of complete samples with it.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import sys
import threading
import time
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import can
    import numpy as np
    from numpy.typing import NDArray

    from canbus.master.dataplane import ForceFrame
    from canbus.master.host import HostManager
    from sim import Scene

DEFAULT_PATCHES = 4
DEFAULT_SECONDS = 3.0
REFRESH_S = 0.25  # live view: at most 4 renders a second, off the data path
SPACING_M = 0.05


def _scene(name: str, patches: int | None) -> Scene:
    """The scene, or its loads and effects on ``patches`` patches at node-IDs 1..N."""
    from sim import load_scene, scene_from_dict
    from skin.errors import ConfigError

    scene = load_scene(name)
    if patches is None or (patches == len(scene.patches)
                           and scene.node_ids == tuple(range(1, patches + 1))):
        return scene
    if not 1 <= patches <= 63:
        raise ConfigError("--patches", f"must be in 1..63 (force nodes at +64), got {patches}")
    data = scene.to_dict()
    side = math.ceil(math.sqrt(patches))
    data["patches"] = [{"node_id": k + 1, "position_m": [SPACING_M * (k % side),
                                                         SPACING_M * (k // side)]}
                       for k in range(patches)]
    for load in data["loads"]:
        load["patches"] = list(range(1, patches + 1))
    faults = data["effects"].get("faults")
    if faults is not None:
        faults["pillars"] = [p for p in faults["pillars"] if p["node_id"] <= patches]
    return scene_from_dict(data)


class _Replay:
    """A precomputed simulation served one step per read, filing each cycle's truth.

    ``on_sync`` must run before the patch server's own SYNC handler (subscribe it first):
    it turns the SYNC counter into the host's cycle number, and ``read`` files the true
    forces of the step it serves under that cycle in ``truth`` / ``known``.
    """

    def __init__(self, resistance_ohm: NDArray[np.float64], force_N: NDArray[np.float64],
                 node_ids: tuple[int, ...], truth: NDArray[np.float64],
                 known: NDArray[np.bool_]) -> None:
        self.resistance_ohm, self.force_N = resistance_ohm, force_N
        self.node_ids = node_ids
        self.pillars = int(resistance_ohm.shape[-1])
        self.truth, self.known = truth, known  # (cycles, patches, 9, 3), (cycles,)
        self.cycle = 0
        self.position = 0

    def on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if data:  # counter = cycle % 240 + 1: the next cycle with that counter
            self.cycle += (data[0] - 2 - self.cycle) % 240 + 1
        else:
            self.cycle += 1

    def read(self) -> NDArray[np.float64]:
        k = self.position % len(self.resistance_ohm)
        self.position += 1
        if self.cycle < len(self.truth):
            self.truth[self.cycle] = self.force_N[k]
            self.known[self.cycle] = True
        sample: NDArray[np.float64] = self.resistance_ohm[k]
        return sample


class _BusClock:
    """Bus timestamps of every SYNC and of every force node's TPDO 7 (a sample's last).

    A listener on the simulated patches' bus, which receives every SYNC and force TPDO
    anyway: a bus of its own would add a copy and a thread's work to every frame of the
    run it measures. A virtual bus stamps a frame once, when it is sent, so every
    receiver sees the same time.
    """

    def __init__(self, force_ids: set[int], tpdo7: dict[int, int]) -> None:
        self.force_ids = force_ids  # every force TPDO COB-ID
        self.tpdo7 = tpdo7  # COB-ID of a force node's TPDO 7 -> its patch
        self.syncs: list[float] = []
        self.ends: dict[int, list[float]] = {p: [] for p in tpdo7.values()}
        self.force_frames = 0

    def __call__(self, msg: can.Message) -> None:
        cob_id = msg.arbitration_id
        if cob_id == 0x080:
            self.syncs.append(msg.timestamp)
        elif cob_id in self.force_ids:
            self.force_frames += 1
            patch = self.tpdo7.get(cob_id)
            if patch is not None:
                self.ends[patch].append(msg.timestamp)


class _Record:
    """What the host published, per cycle and patch, in arrays allocated up front.

    The callback copies a frame into place and keeps the latest per patch for the live
    view: the run allocates no long-lived objects for the garbage collector to walk.
    """

    def __init__(self, cycles: int, node_ids: tuple[int, ...]) -> None:
        import numpy as np

        self.column = {n: j for j, n in enumerate(node_ids)}
        shape = (cycles, len(node_ids))
        self.force = np.zeros((*shape, 9, 3))
        self.valid = np.zeros((*shape, 9), dtype=bool)
        self.complete = np.zeros(shape, dtype=bool)
        self.published = np.zeros(shape, dtype=bool)
        self.latest: dict[int, ForceFrame] = {}

    def __call__(self, frame: ForceFrame) -> None:
        self.latest[frame.patch] = frame
        c, j = frame.cycle, self.column[frame.patch]
        if c < len(self.force):
            self.force[c, j] = frame.force_N
            self.valid[c, j] = frame.valid
            self.complete[c, j] = frame.complete
            self.published[c, j] = frame.published

    def latencies_ms(self, clock: _BusClock) -> NDArray[np.float64]:
        """SYNC -> last force TPDO of every published sample, in ms: the i-th TPDO 7 of a
        force node ends the i-th published sample of its patch."""
        import numpy as np

        syncs = np.asarray(clock.syncs)
        out = []
        for patch, j in self.column.items():
            cycles = np.flatnonzero(self.published[:, j])
            ends = np.asarray(clock.ends[patch][: len(cycles)])
            cycles = cycles[: len(ends)]
            ok = cycles <= len(syncs)
            out.append(1000.0 * (ends[ok] - syncs[cycles[ok] - 1]))
        return np.concatenate(out) if out else np.empty(0)

    def rmse_N(self, truth: NDArray[np.float64], known: NDArray[np.bool_]) -> float:
        """Over the valid taxels of complete samples whose truth is known."""
        import numpy as np

        chosen = self.complete & known[:, None]
        error = (self.force[chosen] - truth[chosen])[self.valid[chosen]]
        return float(np.sqrt(np.mean(error ** 2))) if error.size else math.nan


def _table(host: HostManager, live: _Record, elapsed: float, seconds: float) -> Any:
    import numpy as np
    from rich.table import Table

    table = Table(title=f"skin demo  {elapsed:4.1f} / {seconds:g} s", title_justify="left")
    for column in ("patch", "state", "samples", "incomplete", "peak |F| N", "taxel",
                   "sum Fz N"):
        table.add_column(column, justify="right")
    for node_id, health in sorted(host.health().items()):
        frame = live.latest.get(node_id)
        if frame is None:
            table.add_row(str(node_id), health.state, "0", "0", "-", "-", "-")
            continue
        magnitude = np.linalg.norm(frame.force_N, axis=1)
        k = int(np.argmax(magnitude))
        table.add_row(str(node_id), health.state, str(health.samples), str(health.incomplete),
                      f"{magnitude[k]:.2f}", str(k), f"{frame.force_N[:, 2].sum():.2f}")
    return table


def _line(host: HostManager, live: _Record, elapsed: float) -> str:
    import numpy as np

    stats = host.stats()
    peak, where = 0.0, "-"
    for node_id, frame in sorted(live.latest.items()):
        magnitude = np.linalg.norm(frame.force_N, axis=1)
        if magnitude.max() > peak:
            peak, where = float(magnitude.max()), f"patch {node_id} taxel {int(magnitude.argmax())}"
    return (f"{elapsed:5.1f} s  {stats['samples']:6d} samples  "
            f"{stats['incomplete_samples']} incomplete  peak {peak:.2f} N ({where})")


def _watch(host: HostManager, live: _Record, seconds: float) -> None:
    """Show live forces for ``seconds``: a rich table on a terminal, a line a second if not."""
    started = time.monotonic()
    stop = threading.Event()
    if sys.stdout.isatty():
        from rich.live import Live

        with Live(_table(host, live, 0.0, seconds), auto_refresh=False) as view:
            while not stop.wait(max(0.0, min(REFRESH_S, seconds - (time.monotonic() - started)))):
                elapsed = time.monotonic() - started
                view.update(_table(host, live, elapsed, seconds), refresh=True)
                if elapsed >= seconds:
                    break
        return
    next_line = 1.0
    while (elapsed := time.monotonic() - started) < seconds:
        stop.wait(min(next_line, seconds) - elapsed)
        elapsed = time.monotonic() - started
        if elapsed >= next_line:
            print(_line(host, live, elapsed), flush=True)
            next_line += 1.0


def _figure(value: float, digits: int = 3) -> float | None:
    """A rounded figure for JSON; None (null) where there is none."""
    return None if math.isnan(value) else round(value, digits)


def _demo(args: argparse.Namespace) -> int:
    from skin.commands.cpu import pinned
    from skin.errors import ConfigError

    if not args.seconds > 0:
        raise ConfigError("--seconds", f"must be > 0, got {args.seconds}")
    with pinned(args.cpu) as cpus:  # before the first thread starts: threads inherit it
        return _run_demo(args, cpus)


def _run_demo(args: argparse.Namespace, cpus: set[int] | None) -> int:
    import can
    import canopen
    import numpy as np

    from canbus.device.patch_server import PatchServer
    from canbus.master.host import HostManager
    from canbus.master.hostconfig import HostConfig, PatchConfig, predefined_tpdo_cob_ids
    from sim import Simulator
    from skin.atomic import atomic_write
    from skin.errors import BusError

    scene = _scene(args.scene, args.patches)
    rate_hz = scene.rate_hz
    steps = math.ceil(args.seconds * rate_hz) + int(rate_hz) + 2
    simulated = Simulator(scene).run(steps)
    truth = np.zeros((steps, len(scene.node_ids), 9, 3))
    known = np.zeros(steps, dtype=bool)
    replay = _Replay(simulated.resistance_ohm, simulated.force_N, scene.node_ids, truth, known)
    config = HostConfig(
        patches=tuple(PatchConfig(n, mode=scene.mode) for n in scene.node_ids),
        sync_period_ms=1000.0 / rate_hz, scan_ms=100).check()
    channel = f"skin-demo-{os.getpid()}"
    tpdo7 = {predefined_tpdo_cob_ids(p.force_node)[-1]: p.node_id for p in config.patches}
    patch_net = canopen.Network()
    patch_net.NOTIFIER_CYCLE = 0.05
    patch_net.connect(interface="virtual", channel=channel)
    force_ids = {c for p in config.patches for c in predefined_tpdo_cob_ids(p.force_node)}
    clock = _BusClock(force_ids, tpdo7)
    assert patch_net.notifier is not None
    patch_net.notifier.add_listener(clock)
    host_bus = can.Bus(interface="virtual", channel=channel)
    live = _Record(steps, scene.node_ids)
    server = PatchServer(patch_net, replay)
    patch_net.subscribe(0x080, replay.on_sync)  # before the server's: it labels the cycle
    host = HostManager(host_bus, config)
    # The nodes' object dictionaries are ~50k long-lived objects: a full collection walking
    # them stalled every thread for ~75 ms mid-run. Collect once now and freeze them.
    gc.collect()
    gc.freeze()
    # Before the start: a sample published before the record saw it would still end on
    # the bus clock, and every later sample would be matched to the SYNC before its own.
    host.on_forces(live)
    try:
        with server, host:
            if not host.wait_operational(timeout=10.0):
                states = {n: h.state for n, h in host.health().items()}
                raise BusError(f"the patches did not all become operational: {states}")
            where = "any CPU" if cpus is None else f"CPU {','.join(map(str, sorted(cpus)))}"
            print(f"skin demo: {len(config.patches)} patches ({scene.name}, {scene.mode}, "
                  f"{config.patches[0].decoder}) at {rate_hz:g} Hz on virtual:{channel}, "
                  f"{where}", flush=True)
            started = time.monotonic()
            _watch(host, live, args.seconds)
        seconds = time.monotonic() - started
        stats = host.stats()
    finally:
        gc.unfreeze()
        host_bus.shutdown()
        patch_net.disconnect()
    latency = live.latencies_ms(clock)
    used = stats["frames_in"] - stats["late_frames"] - stats["duplicate_frames"] - \
        stats["malformed_frames"]
    dropped = (server.frames_sent - used) + (stats["frames_out"] - clock.force_frames) + \
        stats["send_errors"]
    p50, p99, worst = (np.percentile(latency, [50, 99, 100]).tolist() if latency.size
                       else [math.nan] * 3)
    record = {
        "patches": len(config.patches), "seconds": round(seconds, 3), "scene": scene.name,
        "mode": scene.mode, "rate_hz": rate_hz, "samples": stats["samples"],
        "complete_samples": stats["complete_samples"],
        "incomplete_samples": stats["incomplete_samples"], "dropped_frames": dropped,
        "samples_per_s": round(stats["samples"] / seconds, 1),
        "latency_ms": {"p50": _figure(p50), "p99": _figure(p99), "max": _figure(worst)},
        "rmse_N": _figure(live.rmse_N(truth, known), 5),
        "decoder": config.patches[0].decoder,
        "sync_overruns": stats["sync_overruns"],
        "cpus": None if cpus is None else sorted(cpus),
    }
    print(f"  samples   {record['samples']} ({record['complete_samples']} complete, "
          f"{record['incomplete_samples']} incomplete) in {seconds:.1f} s = "
          f"{record['samples_per_s']:g}/s; dropped frames {dropped}")
    print(f"  latency   SYNC -> forces on the bus: p50 {p50:.2f} ms, p99 {p99:.2f} ms")
    print(f"  accuracy  rmse {record['rmse_N']:.4f} N against the simulator's true forces")
    if args.json:
        with atomic_write(args.json) as handle:
            handle.write(json.dumps(record, indent=2).encode() + b"\n")
    return 0


def add_subparser(subparsers: Any) -> None:
    from skin.commands.cpu import add_cpu_argument

    parser = subparsers.add_parser(
        "demo", help="simulated patches + the host on a virtual bus: live forces, a summary")
    parser.add_argument("--patches", type=int, default=DEFAULT_PATCHES, metavar="N",
                        help=f"patches, node-IDs 1..N (default {DEFAULT_PATCHES})")
    parser.add_argument("--seconds", type=float, default=DEFAULT_SECONDS, metavar="S",
                        help=f"how long to run (default {DEFAULT_SECONDS:g})")
    parser.add_argument("--scene", default="indenter", metavar="NAME",
                        help="a shipped scene or a .toml path; its loads press every patch "
                             "(default indenter)")
    parser.add_argument("--json", metavar="FILE", help="write the summary figures as JSON")
    add_cpu_argument(parser, default="last")
    parser.set_defaults(func=_demo)
