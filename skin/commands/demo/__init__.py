"""``skin demo``: simulated patches and the host manager on a bus that keeps time.

The scene's patches (``--patches N``: node-IDs 1..N, every load of the scene on every
patch) run as CANopen nodes; the host discovers, configures and starts them, sends SYNC
at the scene's rate, decodes and publishes the forces on the patches' bus. By default
the bus is the timed bus (``canbus.timed``) at 1 Mbit/s: every frame holds the wire for
its exact bits, so the figures are those of a real bus; ``--bus virtual`` is python-can's
zero-time bus, ``--fd`` CAN FD (a whole sample in one frame each way), ``--buses N``
spreads the patches over N buses, each with its own SYNC. Before anything runs, the
bus-load planner (``skin plan``) says whether the traffic fits: a bus it cannot carry is
refused (``--overload`` runs it anyway), one it carries only without worst-case stuffing
is warned about.

Latency is measured on the bus: from a SYNC frame to the last force PDO of the cycle
(``latency_ms``) and of each patch's sample (``sample_latency_ms``); ``wire_ms`` is the
time the cycle's frames held the wire, so a user sees how much is the bus and how much is
canskin. The simulation is computed before the run and served one step per SYNC, so the
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

from skin.commands.common import argtypes
from skin.commands.common.logs import warn

if TYPE_CHECKING:
    import can

    from canbus.busload import Plan
    from canbus.master.host import HostManager
    from canbus.master.hostconfig import HostConfig
    from sim import Scene
    from skin.commands.demo.rig import Record
    from skin.commands.demo.summary import DemoBus

DEFAULT_PATCHES = 4
DEFAULT_SECONDS = 3.0
REFRESH_S = 0.25  # live view: at most 4 renders a second, off the data path
SPACING_M = 0.05
BUS_KINDS = ("timed", "virtual")
WIRE_SNAPSHOT_WINDOW_S = 0.01


def demo_scene(name: str, patches: int | None) -> Scene:
    """The scene, or its loads and effects on ``patches`` patches at node-IDs 1..N."""
    from sim import load_scene, on_patches

    scene = load_scene(name)
    return scene if patches is None else on_patches(scene, patches, SPACING_M)


def _open(kind: str, channel: str, args: argparse.Namespace) -> can.BusABC:
    import can

    if kind == "virtual":
        protocol = can.CanProtocol.CAN_FD if args.fd else can.CanProtocol.CAN_20
        return can.Bus(interface="virtual", channel=channel, protocol=protocol)
    return can.Bus(interface="timed", channel=channel, bitrate=args.bitrate, fd=args.fd,
                   data_bitrate=args.data_bitrate if args.fd else None)


def _plan(args: argparse.Namespace, scene: Scene, heartbeat_ms: int,
          force_heartbeat_ms: int) -> Plan:
    from canbus.busload import plan

    return plan(len(scene.node_ids), scene.rate_hz, scene.mode, args.bitrate,
                data_bitrate=args.data_bitrate if args.fd else None, buses=args.buses,
                forces="same-bus", heartbeat_ms=heartbeat_ms,
                force_heartbeat_ms=force_heartbeat_ms)


def _check_plan(args: argparse.Namespace, plan: Plan) -> None:
    """Refuse a bus the plan says cannot carry the traffic; warn about a tight one."""
    from skin.errors import ConfigError

    worst = max(plan.buses, key=lambda b: b.load_best_pct)
    kind = f"CAN FD {args.bitrate:,}/{args.data_bitrate:,}" if args.fd else \
        f"CAN {args.bitrate:,}"
    numbers = (f"{plan.patches} patches x {plan.rate_hz:g} Hz ({plan.mode}) with their force "
               f"PDOs on {args.buses} bus{'es' if args.buses > 1 else ''} of {kind} bit/s: "
               f"{worst.load_best_pct:.0f}-{worst.load_worst_pct:.0f} % load, "
               f"{worst.cycle_ms_best:.2f}-{worst.cycle_ms_worst:.2f} ms of wire per "
               f"{1000 / plan.rate_hz:g} ms cycle")
    if args.bus == "virtual":
        if not plan.fits:
            warn(f"note: on a real bus this would not fit: {numbers} (skin plan)")
        return
    if worst.load_best_pct > 100.0 and not args.overload:
        raise ConfigError("--patches", f"{numbers}: it cannot fit; use --fd, --buses "
                          f"{math.ceil(worst.load_best_pct / 70)}, fewer patches, or "
                          "--overload to watch it fail")
    if not plan.fits:
        warn(f"warning: {numbers} (skin plan); with worst-case stuffing it does not fit, "
             "so samples may come late")


def _demo(args: argparse.Namespace) -> int:
    from skin.commands.common.cpu import pinned
    from skin.errors import ConfigError

    if not args.seconds > 0:
        raise ConfigError("--seconds", f"must be > 0, got {args.seconds}")
    if args.buses < 1:
        raise ConfigError("--buses", f"must be at least 1, got {args.buses}")
    if args.data_bitrate is not None and not args.fd:
        raise ConfigError("--data-bitrate", "is the CAN FD data phase: add --fd")
    if args.data_bitrate is None:
        args.data_bitrate = 5_000_000
    if args.cpu is None:  # see add_subparser
        args.cpu = "last" if args.bus == "virtual" else "all"
    with pinned(args.cpu) as cpus:  # before the first thread starts: threads inherit it
        return _run_demo(args, cpus)


def _run_demo(args: argparse.Namespace, cpus: set[int] | None) -> int:
    import numpy as np

    from canbus.receiveloop import disconnect
    from sim import Simulator
    from skin.commands.demo import summary as demo_summary
    from skin.commands.demo.rig import Record

    scene = demo_scene(args.scene, args.patches)
    config = _host_config(args, scene)
    plan = _plan(args, scene, config.heartbeat_ms, config.force_heartbeat_ms)
    _check_plan(args, plan)
    steps = math.ceil(args.seconds * scene.rate_hz) + int(scene.rate_hz) + 2
    simulated = Simulator(scene).run(steps)
    truth = np.zeros((steps, len(scene.node_ids), 9, 3))
    known = np.zeros((steps, len(scene.node_ids)), dtype=bool)
    live = Record(steps, scene.node_ids)
    opened: list[DemoBus] = []
    try:
        for name in (b.name for b in config.buses):
            group = tuple(p.node_id for p in config.patches if p.bus == name)
            opened.append(_open_bus(args, name, group, live, simulated, truth, known))
        seconds, stats, gone = _run_host(args, scene, config, cpus, opened, live)
    finally:
        gc.unfreeze()
        for bus in opened:
            disconnect(bus.network)
            bus.host_bus.shutdown()
    record = demo_summary.summary(args, scene, plan, opened, live, stats, seconds, truth,
                                  known, cpus)
    demo_summary.print_summary(record)
    if args.json:
        from skin.atomic import atomic_write

        with atomic_write(args.json) as handle:
            handle.write(json.dumps(record, indent=2).encode() + b"\n")
    if gone is not None:
        from skin.errors import BusError

        raise BusError(f"{gone}: the host cannot hear its patches")
    return 0


def _host_config(args: argparse.Namespace, scene: Scene) -> HostConfig:
    """The host's config: the scene's patches spread over ``--buses`` buses, SYNC at the
    scene's rate."""
    from canbus.busload import spread
    from canbus.master.busconfig import BusConfig
    from canbus.master.hostconfig import HostConfig, PatchConfig
    from skin.errors import ConfigError

    if args.buses > len(scene.node_ids):
        raise ConfigError("--buses", f"{args.buses} buses for {len(scene.node_ids)} patches")
    groups = spread(scene.node_ids, args.buses)
    names = [f"skin{k}" for k in range(len(groups))]
    return HostConfig(
        patches=tuple(PatchConfig(n, mode=scene.mode, bus=names[k])
                      for k, group in enumerate(groups) for n in group),
        sync_period_ms=1000.0 / scene.rate_hz, scan_ms=100,
        buses=tuple(BusConfig(name=name, fd=args.fd) for name in names)).check()


def _open_bus(args: argparse.Namespace, name: str, group: tuple[int, ...], live: Record,
              simulated: Any, truth: Any, known: Any) -> DemoBus:
    """One bus of the demo: the host's end, and the patches of ``group`` served from the
    precomputed simulation on a canopen Network of their own, with the bus clock."""
    from functools import partial

    import canopen

    from canbus.busio import ResilientBus
    from canbus.device.patch_server import PatchServer
    from canbus.receiveloop import connect
    from skin.commands.demo.rig import BusClock, Replay
    from skin.commands.demo.summary import DemoBus

    channel = f"demo-{os.getpid()}-{name}"
    # Each opened again when it keeps failing (canbus.busio); the host's first: the
    # patches' frames need it.
    host_bus = ResilientBus(partial(_open, args.bus, channel, args), name=name)
    patch_net = canopen.Network(ResilientBus(partial(_open, args.bus, channel, args),
                                             name=f"{name} (patches)"))
    patch_net.NOTIFIER_CYCLE = 0.05
    connect(patch_net)
    timed = args.bus == "timed"
    clock = BusClock.for_patches(group, fd=args.fd, bitrate=args.bitrate if timed else None,
                                 data_bitrate=args.data_bitrate if timed and args.fd else None)
    assert patch_net.notifier is not None
    patch_net.notifier.add_listener(clock)
    columns = [live.column[n] for n in group]
    replay = Replay(simulated.resistance_ohm, simulated.force_N, group, columns, truth, known)
    server = PatchServer(patch_net, replay)
    patch_net.subscribe(0x080, replay.on_sync)  # before the server's: it labels cycles
    return DemoBus(name, group, host_bus, patch_net, server, clock)


def _run_host(args: argparse.Namespace, scene: Scene, config: HostConfig,
              cpus: set[int] | None, opened: list[DemoBus],
              live: Record) -> tuple[float, dict[str, int], str | None]:
    """The host on the demo's buses, the patches served, for ``--seconds`` (or until a stop
    signal): the run's length, the host's counters and the bus it lost for good if any."""
    from canbus.master.host import HostManager
    from skin.commands.common.signals import until_stopped
    from skin.errors import BusError

    host = HostManager({b.name: b.host_bus for b in opened}, config)
    # The nodes' object dictionaries are ~50k long-lived objects: a full collection
    # walking them stalled every thread for ~75 ms mid-run. Collect once, freeze them.
    gc.collect()
    gc.freeze()
    # Before the start: a sample published before the record saw it would still end on
    # the bus clock, and every later sample would be matched to the SYNC before its own.
    host.on_forces(live)
    for bus in opened:
        bus.server.start()
    try:
        with host:
            if not host.wait_operational(timeout=10.0):
                states = {n: h.state for n, h in host.health().items()}
                raise BusError(f"the patches did not all become operational: {states}")
            print(_banner(args, scene, config, cpus), flush=True)
            for bus in opened:
                bus.wire_start = _wire(bus.host_bus)
                notifier = host.links[bus.name].network.notifier
                if args.bus == "timed" and notifier is not None:  # only appends: off the path
                    notifier.add_listener(bus.clock.host_side)
            started = time.monotonic()
            with until_stopped():  # Ctrl-C, SIGTERM, SIGHUP: the summary all the same
                _watch(host, live, args.seconds, scene)
            for bus in opened:
                bus.wire_end = _wire(bus.host_bus)
        # the host stopped: its last counts
        return time.monotonic() - started, host.stats(), host.bus_gone()
    finally:
        for bus in opened:
            bus.server.stop()
            bus.frames_sent = bus.server.frames_sent


def _wire(bus: can.BusABC) -> Any:
    stats = getattr(bus, "wire_stats", None)
    # Totals only: a short load window keeps the snapshot from holding the wire's lock.
    return stats(WIRE_SNAPSHOT_WINDOW_S) if callable(stats) else None


def _banner(args: argparse.Namespace, scene: Scene, config: Any, cpus: set[int] | None) -> str:
    where = "any CPU" if cpus is None else f"CPU {','.join(map(str, sorted(cpus)))}"
    kind = "virtual (zero-time)" if args.bus == "virtual" else (
        f"timed CAN FD {args.bitrate:,}/{args.data_bitrate:,} bit/s" if args.fd else
        f"timed CAN {args.bitrate:,} bit/s")
    buses = f" on {args.buses} buses" if args.buses > 1 else ""
    return (f"skin demo: {len(config.patches)} patches ({scene.name}, {scene.mode}, "
            f"{config.patches[0].decoder}) at {scene.rate_hz:g} Hz, {kind}{buses}, {where}")


def _line(host: HostManager, live: Record, elapsed: float) -> str:
    import numpy as np

    stats = host.stats()
    peak, where = 0.0, "-"
    for node_id, frame in sorted(live.latest.items()):
        magnitude = np.linalg.norm(frame.force_N, axis=1)
        if magnitude.max() > peak:
            peak, where = float(magnitude.max()), f"patch {node_id} taxel {int(magnitude.argmax())}"
    return (f"{elapsed:5.1f} s  {stats['samples']:6d} samples  "
            f"{stats['incomplete_samples']} incomplete  peak {peak:.2f} N ({where})")


def _watch(host: HostManager, live: Record, seconds: float, scene: Scene) -> None:
    """Show live forces for ``seconds``: on a terminal the skin itself (``skin view``'s
    live heat map, drawn on its own thread, never holding up the data path); else a line a
    second."""
    started = time.monotonic()
    stop = threading.Event()
    if sys.stdout.isatty():
        from skin.commands.view.layout import layout_from_positions
        from skin.commands.view.live import LiveThread
        from skin.commands.view.term import SkinView

        layout = layout_from_positions({p.node_id: p.position_m for p in scene.patches},
                                       "scene")
        view = SkinView(layout, title=f"skin demo ({scene.name})")
        host.on_forces(view.update)

        def label() -> str:
            return f"{time.monotonic() - started:4.1f} / {seconds:g} s"

        with LiveThread(view, refresh_hz=1 / REFRESH_S, label=label):
            while time.monotonic() - started < seconds and host.bus_gone() is None:
                stop.wait(min(REFRESH_S, seconds - (time.monotonic() - started)))
        host.remove_callback(view.update)
        return
    next_line = 1.0
    while (elapsed := time.monotonic() - started) < seconds and host.bus_gone() is None:
        stop.wait(min(next_line, seconds, elapsed + REFRESH_S) - elapsed)
        elapsed = time.monotonic() - started
        if elapsed >= next_line:
            print(_line(host, live, elapsed), flush=True)
            next_line += 1.0


def add_subparser(subparsers: Any) -> None:
    from skin.commands.common.cpu import add_cpu_argument

    parser = subparsers.add_parser(
        "demo", help="simulated patches + the host on a timed bus: live forces, a summary")
    parser.add_argument("--patches", type=argtypes.count("patches", 1, 63),
                        default=DEFAULT_PATCHES, metavar="N",
                        help=f"patches, node-IDs 1..N (default {DEFAULT_PATCHES})")
    parser.add_argument("--seconds", type=argtypes.seconds, default=DEFAULT_SECONDS, metavar="S",
                        help=f"how long to run (default {DEFAULT_SECONDS:g})")
    parser.add_argument("--scene", default="indenter", metavar="NAME",
                        help="a shipped scene or a .toml path; its loads press every patch "
                             "(default indenter)")
    parser.add_argument("--bus", choices=BUS_KINDS, default="timed",
                        help="timed: a simulated wire that keeps time (default); virtual: "
                             "python-can's zero-time bus")
    parser.add_argument("--bitrate", type=argtypes.bitrate, default=1_000_000, metavar="B",
                        help="nominal bit rate of the timed bus (default 1000000)")
    parser.add_argument("--fd", action="store_true",
                        help="CAN FD: a patch answers SYNC in one frame, its forces go in one")
    parser.add_argument("--data-bitrate", type=argtypes.bitrate, default=None, metavar="B",
                        help="CAN FD data phase (default 5000000)")
    parser.add_argument("--buses", type=argtypes.buses, default=1, metavar="N",
                        help="spread the patches over N buses, each with its own SYNC")
    parser.add_argument("--overload", action="store_true",
                        help="run even when the plan says the bus cannot carry the traffic")
    parser.add_argument("--json", type=argtypes.output_file, metavar="FILE",
                        help="write the summary figures as JSON")
    add_cpu_argument(parser, default="last with --bus virtual, else all")
    # On the zero-time bus one CPU for every thread keeps a cycle's hand-offs in one cache;
    # the timed bus adds a wire thread per bus, and the run needs both CPUs of a small host.
    parser.set_defaults(func=_demo, cpu=None, runs_until_stopped=True)
