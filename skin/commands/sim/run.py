"""``skin sim run SCENE``: the scene's patches as CANopen nodes on a bus until stopped.

One process serves every patch of the scene (``--patches N``: node-IDs 1..N, every load of
the scene on every patch, as ``skin demo --patches`` makes them): the simulator steps all
of them at the scene's rate on its own clock and each SYNC picks up the latest sample
(``canbus.device.patch_server``). Before the bus opens, the bus-load planner (``skin plan``)
says on stderr when one bus could not carry the patches' frames with the force PDOs a host
republishes beside them; ``--buses N`` spreads the patches over N buses in node order, each
answering its own SYNC:

* udp_multicast: the same group on N ports, the given one (python-can's 43113 unless
  ``--bus-kwargs port=P``) and the next N-1;
* virtual and timed: channels ``CHANNEL0`` .. ``CHANNEL<N-1>``;
* any interface: ``-c CH0,CH1,...`` names the N channels.

Ctrl-C, SIGTERM or SIGHUP (or ``--seconds``) ends it normally: the summary, ``--json``,
exit status 0. ``--truth F.csv`` also writes the simulator's true forces as reference
forces (keyed by the SYNC counter each answer answers and the SYNC's time;
``canbus.device.truth``); each SYNC then steps the simulator once, so every answer has its
own step (one bus only).
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import gc
import json
import os
import threading
import time
from typing import TYPE_CHECKING, Any

from skin.commands.common import argtypes
from skin.commands.common.logs import warn

if TYPE_CHECKING:
    import canopen

    from canbus.busload import Plan
    from sim import Scene

_NOTIFIER_CYCLE_S = 0.05
_POLL_S = 0.1  # how often a run looks at its buses
SPACING_M = 0.05
UDP_DEFAULT_PORT = 43113  # python-can's udp_multicast default
NO_WIRE = ("virtual", "udp_multicast")
"""Interfaces that carry frames without bits on a wire: a load above the planner's target
is no concern there (one that cannot fit a real bus still is said)."""
AHEAD_S = 0.1
"""The simulator computes this much of the scene at once (one vectorised run of 10 steps at
100 Hz costs about what two single steps cost), then the patches read it step by step."""


def scene_on_patches(name: str, patches: int | None) -> Scene:
    """The scene, or its loads and effects on ``patches`` patches at node-IDs 1..N (a grid
    5 cm apart), every load on every patch."""
    from sim import load_scene, on_patches

    scene = load_scene(name)
    return scene if patches is None else on_patches(scene, patches, SPACING_M)


def bus_namespaces(args: argparse.Namespace, buses: int) -> list[argparse.Namespace]:
    """The python-can flags of each of ``buses`` buses (see the module's docstring)."""
    from skin.errors import ConfigError

    channel = getattr(args, "channel", None)
    if isinstance(channel, str) and "," in channel:
        channels: list[Any] = [c.strip() for c in channel.split(",")]
        if len(channels) != buses:
            raise ConfigError("--channel", f"{len(channels)} channels for --buses {buses}")
    elif buses == 1:
        return [args]
    elif args.interface == "udp_multicast":
        from skin.commands.common.busopen import python_can_settings

        given = (getattr(args, "bus_kwargs", None) or {}).get("port")
        base = int(given if given is not None else
                   python_can_settings().get("port", UDP_DEFAULT_PORT))
        out = []
        for k in range(buses):
            each = copy.copy(args)
            each.bus_kwargs = {**(getattr(args, "bus_kwargs", None) or {}), "port": base + k}
            out.append(each)
        return out
    elif args.interface in ("virtual", "timed"):
        channels = [f"{channel}{k}" for k in range(buses)]
    else:
        raise ConfigError("--buses", f"name the {buses} channels of {args.interface}: "
                                     "-c CH0,CH1,...")
    out = []
    for each_channel in channels:
        each = copy.copy(args)
        each.channel = each_channel
        out.append(each)
    return out


def _describe(args: argparse.Namespace) -> str:
    port = (getattr(args, "bus_kwargs", None) or {}).get("port")
    where = f"{args.interface}:{getattr(args, 'channel', '?')}"
    return f"{where} port {port}" if port is not None else where


def plan_for(scene: Scene, args: argparse.Namespace) -> Plan:
    """The planner's figures of the scene's patches with their force PDOs beside them."""
    from canbus.busload import plan

    fd = bool(getattr(args, "fd", False))
    bitrate = int(getattr(args, "bitrate", None) or 1_000_000)
    data_bitrate = int(getattr(args, "data_bitrate", None) or 5_000_000) if fd else None
    return plan(len(scene.node_ids), scene.rate_hz, scene.mode, bitrate,
                data_bitrate=data_bitrate, buses=args.buses, forces="same-bus")


def _warn_if_tight(scene: Scene, args: argparse.Namespace, planned: Plan) -> None:
    """One line on stderr when the plan says the buses cannot carry the traffic, or, on a bus
    with a wire (timed, socketcan, ...), carry it above the target load."""
    from canbus.busload import plan

    if planned.fits and (not planned.over_target or args.interface in NO_WIRE):
        return  # the target is a margin for a wire's worst case; these buses have none
    n = len(scene.node_ids)
    enough = next((k for k in range(args.buses + 1, n + 1)
                   if not plan(n, planned.rate_hz, planned.mode, planned.bitrate,
                               data_bitrate=planned.data_bitrate, buses=k,
                               forces="same-bus").over_target), None)
    kind = (f"CAN FD {planned.bitrate:,}/{planned.data_bitrate:,}" if planned.data_bitrate
            else f"CAN {planned.bitrate:,}")
    buses = f"{args.buses} bus{'es' if args.buses > 1 else ''}"
    verdict = "cannot carry" if not planned.fits else "is above the 70 % target for"
    advice = f"--buses {enough}" if enough else "fewer patches"
    warn(f"warning: {buses} of {kind} bit/s {verdict} {n} patches x {planned.rate_hz:g} Hz "
         f"({planned.mode}) with their force PDOs: {planned.load_best_pct:.0f}-"
         f"{planned.load_worst_pct:.0f} % load on {planned.worst_bus}; use {advice}"
         f"{'' if planned.data_bitrate else ' or CAN FD'} on a real bus (skin plan)")


def _run(args: argparse.Namespace) -> int:
    from skin.commands.common.cpu import pinned

    with pinned(args.cpu):  # before the buses and the server start their threads
        return _run_pinned(args)


def _run_pinned(args: argparse.Namespace) -> int:
    from functools import partial

    import canopen

    from canbus.busio import ResilientBus
    from canbus.receiveloop import connect, disconnect
    from skin.commands.common.busopen import announce, choose_bus, open_bus
    from skin.errors import ConfigError

    source = None
    if args.robot is not None:
        from skin.commands.sim.robot import probe_source

        scene, source = probe_source(args)
    else:
        scene = scene_on_patches(args.scene, args.patches)
    if not 1 <= args.buses <= len(scene.node_ids):
        raise ConfigError("--buses", f"must be in 1..{len(scene.node_ids)} (one patch or more "
                                     f"on each bus), got {args.buses}")
    if args.truth and args.buses > 1:
        raise ConfigError("--truth", "writes one bus's answers: use it with --buses 1")
    described = choose_bus(args, command="skin sim run")
    planned = plan_for(scene, args)
    _warn_if_tight(scene, args, planned)
    flags = bus_namespaces(args, args.buses)
    networks: list[canopen.Network] = []
    try:
        for each in flags:  # opened again when they keep failing (canbus.busio)
            network = canopen.Network(ResilientBus(partial(open_bus, each),
                                                   name=_describe(each)))
            # canopen's notifier blocks in recv() for up to NOTIFIER_CYCLE (1 s by default)
            # and disconnect() joins it: a short cycle makes --seconds S end after ~S.
            network.NOTIFIER_CYCLE = _NOTIFIER_CYCLE_S
            connect(network)  # canopen's listeners on a notifier that survives the bus
            networks.append(network)
        announce("skin sim run", described, sends=True)
        return _serve(args, scene, networks, flags, planned, source)
    finally:
        for network in networks:
            disconnect(network)


def _serve(args: argparse.Namespace, scene: Scene, networks: list[canopen.Network],
           flags: list[argparse.Namespace], planned: Plan, given: Any = None) -> int:
    from canbus.busio import gone
    from canbus.device.patch_server import PatchServer
    from canbus.device.source import SimulatorSource
    from canbus.device.truth import TruthSource, truth_log
    from sim import Simulator
    from skin.atomic import atomic_write
    from skin.commands.common.signals import until_stopped
    from skin.commands.sim.identity import patch_identities

    truth = None
    if given is not None:  # the robot's probe scene (--robot), one loop computed, replayed
        source = given
    else:
        simulator = Simulator(scene, seed=args.seed)
        truth = TruthSource(simulator) if args.truth else None
        ahead = max(1, round(AHEAD_S * scene.rate_hz))
        source = truth or SimulatorSource(simulator, ahead=ahead)
    # With --truth each SYNC reads its own step in the SYNC handler (no sample thread).
    server = PatchServer(networks, source, event_rate_hz=0.0 if truth else scene.rate_hz,
                         accept_only_consumed=True, **patch_identities(args, scene))
    # The nodes' object dictionaries are tens of thousands of long-lived objects, and every
    # sample allocates: a full collection walking them would stall the answers. Freeze them.
    gc.collect()
    gc.freeze()
    log = None
    try:
        with server, (truth_log(args.truth, networks[0], truth, server.nodes) if truth
                      else contextlib.nullcontext()) as log, until_stopped() as stopped:
            started, cpu0 = time.monotonic(), os.times()
            _announce(scene, server, flags)
            _until(args.seconds, started, networks, server.failed)
    finally:
        gc.unfreeze()
    elapsed, cpu1 = time.monotonic() - started, os.times()
    cpu = (cpu1.user - cpu0.user + cpu1.system - cpu0.system) / max(elapsed, 1e-9)
    _summary(args, server, log, elapsed, cpu)
    if args.json:
        record = _record(scene, server, flags, planned, elapsed, cpu)
        record["stopped_by"] = stopped.signal
        record["bus_gone"] = gone(n.bus for n in networks)
        record["source_failed"] = None if server.failure is None else repr(server.failure)
        if log is not None:
            record.update(truth_samples=log.writer.samples, truth_late=log.late)
        with atomic_write(args.json) as handle:
            handle.write(json.dumps(record, indent=2).encode() + b"\n")
    _raise_if_failed(server, networks)
    return 0


def _summary(args: argparse.Namespace, server: Any, log: Any, elapsed: float,
             cpu: float) -> None:
    """What was served, and a warning if answers came late."""
    p50, p99 = server.answer_ms()
    answers = (f"; SYNC to its answer's last send p50 {p50:.2f} ms, p99 {p99:.2f} ms"
               if server.sync_count else "")
    print(f"served {server.sync_count} SYNCs, sent {server.frames_sent} TPDOs in "
          f"{elapsed:.1f} s, CPU {100 * cpu:.1f} %{answers}")
    if server.late_answers:
        warn(f"warning: {server.late_answers} of {server.sync_count} answers ended after the "
             "next SYNC was due: this process cannot send that many frames a cycle; serve "
             "fewer patches per process, at a lower rate, or in CAN FD (skin bench server "
             "measures what one core serves)")
    if log is not None:
        print(f"truth: {log.writer.samples} samples -> {args.truth} ({log.late} answers sent "
              "over half a SYNC period late: no truth)")


def _raise_if_failed(server: Any, networks: list[canopen.Network]) -> None:
    """The run's end was a failure: the simulator's, or a bus gone for good."""
    from canbus.busio import gone
    from skin.errors import BusError, SourceError

    if server.failure is not None:
        raise SourceError(f"the simulator failed ({type(server.failure).__name__}: "
                          f"{server.failure}): the patches sent EMCY 0x6100 and stopped "
                          "answering")
    lost = gone(n.bus for n in networks)
    if lost is not None:
        raise BusError(f"{lost}: the patches cannot be heard")


def _until(seconds: float | None, started: float, networks: list[canopen.Network],
           failed: threading.Event) -> None:
    """Wait out ``seconds`` from ``started`` (None: until a stop signal), or until a bus is
    gone for good or the patches' source ``failed``."""
    from canbus.busio import gone

    deadline = None if seconds is None else started + seconds
    while (deadline is None or time.monotonic() < deadline) and \
            gone(n.bus for n in networks) is None and not failed.is_set():
        failed.wait(_POLL_S if deadline is None else
                    max(0.0, min(_POLL_S, deadline - time.monotonic())))


def _record(scene: Scene, server: Any, flags: list[argparse.Namespace], planned: Plan,
            elapsed: float, cpu: float) -> dict[str, Any]:
    """The run's ``--json`` figures: what was served, per bus, against the plan."""
    p50, p99 = server.answer_ms()
    return {"scene": scene.name, "patches": len(scene.node_ids), "mode": scene.mode,
            "seconds": elapsed, "syncs": server.sync_count,
            "frames": server.frames_sent, "cpu_share": cpu,
            "answer_ms": {"p50": p50, "p99": p99}, "late_answers": server.late_answers,
            "buses": [{"bus": _describe(each), "nodes": [n.node_id for n in bus.nodes],
                       "syncs": bus.syncs, "frames": bus.frames_sent}
                      for bus, each in zip(server.buses, flags, strict=True)],
            "plan": {"fits": planned.fits, "over_target": planned.over_target,
                     "load_pct": [planned.load_best_pct, planned.load_worst_pct]}}


def _announce(scene: Scene, server: Any, flags: list[argparse.Namespace]) -> None:
    for bus, each in zip(server.buses, flags, strict=True):
        waiting = [node for node in bus.nodes if not node.configured]
        if waiting:
            serials = ", ".join(f"0x{node.identity.serial:08X}" for node in waiting)
            print(f"scene {scene.name}: {len(waiting)} patches wait for LSS (serial numbers "
                  f"{serials}) on {_describe(each)}", flush=True)
        ids = _ids([node.node_id for node in bus.nodes if node.configured])
        if not ids:
            continue
        print(f"scene {scene.name}: nodes {ids} ({server.nodes[0].mode}) on "
              f"{_describe(each)}", flush=True)
    print("Ctrl-C stops", flush=True)


def _ids(ids: list[int]) -> str:
    if len(ids) > 2 and ids == list(range(ids[0], ids[-1] + 1)):
        return f"{ids[0]}-{ids[-1]}"
    return ", ".join(map(str, ids))


def add_subparser(group_subparsers: Any) -> None:
    from skin.commands.common.cpu import add_cpu_argument
    from skin.commands.sim.identity import add_identity_arguments

    parser = group_subparsers.add_parser(
        "run", help="the scene's patches as nodes on a bus",
        description="The scene's patches as CANopen nodes on a bus until Ctrl-C or --seconds. "
                    "--buses N spreads them in node order over N buses: udp_multicast the "
                    "same group on N ports from the given one (--bus-kwargs port=P, default "
                    "43113), virtual and timed channels CHANNEL0..CHANNEL<N-1>, any "
                    "interface -c CH0,CH1,...")
    parser.add_argument("scene", metavar="SCENE", help="a shipped scene name or a .toml path")
    parser.add_argument("--patches", type=argtypes.patches, default=None, metavar="N",
                        help="the scene's loads and effects on N patches, node-IDs 1..N")
    parser.add_argument("--buses", type=argtypes.buses, default=1, metavar="N",
                        help="spread the patches over N buses in node order (default 1)")
    parser.add_argument("--seconds", type=argtypes.seconds, default=None, metavar="S",
                        help="stop after S seconds (default: run until Ctrl-C)")
    parser.add_argument("--seed", type=argtypes.seed, default=None,
                        help="random seed (default: the scene's)")
    parser.add_argument("--json", type=argtypes.output_file, metavar="FILE",
                        help="write the run's figures as JSON")
    parser.add_argument("--truth", type=argtypes.output_file, metavar="F.csv",
                        help="also write the true forces of every answer as reference forces "
                             "(docs/calibrate.md); each SYNC then steps the simulator once "
                             "(one bus only)")
    parser.add_argument("--robot", metavar="HOST.toml", default=None,
                        help="SCENE is a probe scene (examples/robot/probe.toml) pressing the "
                             "patches this host config places on the robot's links "
                             "(docs/robot.md)")
    add_identity_arguments(parser)
    add_cpu_argument(parser, default="all")
    argtypes.add_bus_arguments(parser)
    parser.set_defaults(func=_run, runs_until_stopped=True)
