"""``skin run CONFIG.toml``: the host manager on any python-can bus until stopped.

The config is read and checked before the bus is opened, so a bad config fails at once
with one line naming the field. Bus flags are python-can's own (``-i``, ``-c``, ``-b``,
...; without them, python-can's configuration file or environment). While running,
every change of a patch's state and every unknown node is printed on a line; Ctrl-C
(or ``--seconds``) stops the host and prints a summary.

``--listen-only`` (or ``host.listen_only = true``): decode what another master runs, or a
recording ``skin replay`` sends, and transmit nothing. ``--cpu 3`` runs every thread of
the host on CPU 3 (see ``skin.commands.cpu``).
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import json
import threading
import time
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import can

    from canbus.master.discovery import UnknownNode
    from canbus.master.host import HostManager
    from canbus.master.hostconfig import HostConfig

POLL_S = 0.1


def _open_bus(args: argparse.Namespace) -> can.BusABC:
    import can.cli

    from skin.errors import BusError

    try:
        return can.cli.create_bus_from_namespace(args)
    except argparse.ArgumentError as err:
        cause = err.__cause__ or err
        raise BusError(f"cannot open the bus: {type(cause).__name__}: {cause}") from err


def _report_unknown(node: UnknownNode) -> None:
    print(f"node {node.node_id}: {node.reason}; left alone", flush=True)


def _follow(host: HostManager, seconds: float | None) -> None:
    """Print each patch's state when it changes, until ``seconds`` or Ctrl-C."""
    deadline = None if seconds is None else time.monotonic() + seconds
    shown: dict[int, str] = {}
    tick = threading.Event()
    while deadline is None or time.monotonic() < deadline:
        for node_id, health in sorted(host.health().items()):
            if shown.get(node_id) != health.state:
                shown[node_id] = health.state
                detail = f" ({health.error})" if health.error else ""
                print(f"patch {node_id}: {health.state}{detail}", flush=True)
        left = POLL_S if deadline is None else min(POLL_S, deadline - time.monotonic())
        tick.wait(max(0.0, left))


def _run(args: argparse.Namespace) -> int:
    from canbus.master.hostconfig import load_host_config
    from skin.commands.cpu import pinned

    config = load_host_config(args.config)
    with pinned(args.cpu):  # before the bus and the host start their threads
        return _run_host(args, config)


def _run_host(args: argparse.Namespace, config: HostConfig) -> int:
    from canbus.master.host import HostManager
    from canbus.tools.recorder import enlarge_receive_buffer
    from skin.atomic import atomic_write

    bus = _open_bus(args)
    if args.rcvbuf:
        enlarge_receive_buffer(bus, args.rcvbuf)
    started = time.monotonic()
    try:
        host = HostManager(bus, config, on_unknown=_report_unknown,
                           listen_only=True if args.listen_only else None)
        gc.collect()  # the object dictionaries are long-lived: keep the collector off them
        gc.freeze()
        n = len(config.patches)
        patches = f"{n} patch{'es' if n > 1 else ''} on {bus.channel_info}"
        if host.listen_only:
            print(f"host (listen-only): {patches}, following the SYNCs on the bus, "
                  "decoding; nothing is sent; Ctrl-C stops", flush=True)
        else:
            forces = ", ".join(f"{p.node_id}->{p.force_node}" for p in config.patches)
            print(f"host: {patches}, SYNC every {config.sync_period_ms:g} ms, forces "
                  f"published as nodes {forces}; Ctrl-C stops", flush=True)
        with host:
            try:
                _follow(host, args.seconds)
            except KeyboardInterrupt:
                print("stopping", flush=True)
        stats = host.stats()
        health = host.health()
    finally:
        gc.unfreeze()
        bus.shutdown()
    elapsed = time.monotonic() - started
    verb = "decoded" if host.listen_only else "published"
    print(f"{verb} {stats['samples']} samples ({stats['complete_samples']} complete, "
          f"{stats['incomplete_samples']} incomplete) in {elapsed:.1f} s; frames in "
          f"{stats['frames_in']}, out {stats['frames_out']}, late {stats['late_frames']}, "
          f"duplicate {stats['duplicate_frames']}")
    if args.json:
        record: dict[str, Any] = {
            "config": config.source, "listen_only": host.listen_only,
            "seconds": round(elapsed, 3), "stats": stats,
            "patches": {str(n): dataclasses.asdict(h) for n, h in health.items()},
            "unknown_nodes": sorted(host.unknown_nodes),
        }
        with atomic_write(args.json) as handle:
            handle.write(json.dumps(record, indent=2).encode() + b"\n")
    return 0


def add_subparser(subparsers: Any) -> None:
    import can.cli

    from skin.commands.busargs import add_rcvbuf_argument
    from skin.commands.cpu import add_cpu_argument

    parser = subparsers.add_parser("run", help="the host manager on a bus (CONFIG.toml)")
    parser.add_argument("config", metavar="CONFIG", help="host config (see examples/host.toml)")
    parser.add_argument("--seconds", type=float, default=None, metavar="S",
                        help="stop after S seconds (default: run until Ctrl-C)")
    parser.add_argument("--listen-only", action="store_true",
                        help="decode what another master runs (or `skin replay` sends) and "
                             "transmit nothing: no scan, SDO, NMT, SYNC or force node "
                             "(default: host.listen_only of the config)")
    parser.add_argument("--json", metavar="FILE", help="write the run's figures as JSON")
    add_cpu_argument(parser, default="all")
    add_rcvbuf_argument(parser)
    can.cli.add_bus_arguments(parser)
    parser.set_defaults(func=_run)
