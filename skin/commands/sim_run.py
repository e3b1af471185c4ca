"""``skin sim run SCENE``: the scene's patches as CANopen nodes on a bus until stopped.

Ctrl-C, SIGTERM or SIGHUP (or ``--seconds``) ends it normally: the summary, ``--json``,
exit status 0. ``--truth F.csv`` also writes the simulator's true forces as reference
forces (keyed by the SYNC counter each answer answers and the SYNC's time;
``canbus.device.truth``); each SYNC then steps the simulator once, so every answer has its
own step.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import threading
import time
from typing import Any

_NOTIFIER_CYCLE_S = 0.05


def _run(args: argparse.Namespace) -> int:
    import can.cli
    import canopen

    from canbus.device.patch_server import PatchServer
    from canbus.device.source import SimulatorSource
    from canbus.device.truth import TruthSource, truth_log
    from sim import Simulator, load_scene
    from skin.atomic import atomic_write
    from skin.commands.busargs import default_channel
    from skin.commands.signals import until_stopped

    scene = load_scene(args.scene)
    default_channel(args)
    network = canopen.Network(can.cli.create_bus_from_namespace(args))
    # canopen's notifier blocks in recv() for up to NOTIFIER_CYCLE (1 s by default) and
    # disconnect() joins it: a short cycle makes --seconds S end after ~S, not S + 1.
    network.NOTIFIER_CYCLE = _NOTIFIER_CYCLE_S
    network.connect()  # starts canopen's notifier on the bus it was given
    simulator = Simulator(scene, seed=args.seed)
    truth = TruthSource(simulator) if args.truth else None
    source = truth or SimulatorSource(simulator)
    started, cpu0 = time.monotonic(), os.times()
    stop = threading.Event()
    try:
        with PatchServer(network, source, event_rate_hz=0.0 if truth else scene.rate_hz) \
                as server, (truth_log(args.truth, network, truth, server.nodes) if truth
                            else contextlib.nullcontext()) as log, \
                until_stopped() as stopped:  # from the line that tells how to stop it
            ids = ", ".join(str(n) for n in source.node_ids)
            print(f"scene {scene.name}: nodes {ids} ({server.nodes[0].mode}) on "
                  f"{args.interface}:{args.channel}; Ctrl-C stops", flush=True)
            stop.wait(args.seconds)
    finally:
        network.disconnect()
    elapsed, cpu1 = time.monotonic() - started, os.times()
    cpu = (cpu1.user - cpu0.user + cpu1.system - cpu0.system) / max(elapsed, 1e-9)
    print(f"served {server.sync_count} SYNCs, sent {server.frames_sent} TPDOs in "
          f"{elapsed:.1f} s, CPU {100 * cpu:.1f} %")
    if log is not None:
        print(f"truth: {log.writer.samples} samples -> {args.truth} ({log.late} answers sent "
              "over half a SYNC period late: no truth)")
    if args.json:
        record = {"scene": scene.name, "seconds": elapsed, "syncs": server.sync_count,
                  "frames": server.frames_sent, "cpu_share": cpu,
                  "stopped_by": stopped.signal}
        if log is not None:
            record.update(truth_samples=log.writer.samples, truth_late=log.late)
        with atomic_write(args.json) as handle:
            handle.write(json.dumps(record, indent=2).encode() + b"\n")
    return 0


def add_subparser(group_subparsers: Any) -> None:
    import can.cli

    parser = group_subparsers.add_parser("run", help="the scene's patches as nodes on a bus")
    parser.add_argument("scene", metavar="SCENE", help="a shipped scene name or a .toml path")
    parser.add_argument("--seconds", type=float, default=None, metavar="S",
                        help="stop after S seconds (default: run until Ctrl-C)")
    parser.add_argument("--seed", type=int, default=None, help="random seed (default: the scene's)")
    parser.add_argument("--json", metavar="FILE", help="write the run's figures as JSON")
    parser.add_argument("--truth", metavar="F.csv",
                        help="also write the true forces of every answer as reference forces "
                             "(docs/calibrate.md); each SYNC then steps the simulator once")
    can.cli.add_bus_arguments(parser)
    parser.set_defaults(func=_run, interface="virtual")
