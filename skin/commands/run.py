"""``skin run CONFIG.toml``: the host manager on any python-can bus until stopped.

The config is read and checked before a bus is opened, so a bad config fails at once
with one line naming the field. The buses are the config's (``[bus]``, or several
``[[buses]]``); python-can's bus flags (``-i``, ``-c``, ``-b``, ``--fd`` ...) go over the
one bus of a config (:mod:`skin.commands.common.hostbus`); with no bus anywhere, one line says so.
While running, every change of a patch's state and every unknown node is printed on a
line (the host's own log record of it, printed once, on stdout), and ``--status-every S``
prints a health line every S seconds; Ctrl-C, SIGTERM or SIGHUP (or ``--seconds``) stops
the host, whatever it is doing (a scan, a set-up, an SDO transfer), and prints a summary.

Each bus is a ``canbus.busio.ResilientBus``: what its ``recv`` raises is survived, a bus
that keeps failing is opened again; one that cannot be had back ends the run with exit
status 1 and one line (the summary and ``--json`` first), so that a service manager
restarts it.

``--record F`` (.log, .asc, .blf, .pcap, .mcap) records every frame on the host's buses,
its own included, and in an .mcap also every force sample it published
(:mod:`skin.commands.common.hostrecord`, docs/mcap.md), on threads of its own.

``--listen-only`` (or ``host.listen_only = true``): decode what another master runs, or a
recording ``skin replay`` sends, and transmit nothing. ``--cpu 3`` runs every thread of
the host on CPU 3 (see ``skin.commands.common.cpu``), ``--realtime 50`` under SCHED_FIFO
at priority 50 (``skin.commands.common.realtime``).
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import logging
import threading
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

from skin.commands.common import argtypes

if TYPE_CHECKING:
    import can

    from canbus.master.channel import ForceFrame
    from canbus.master.host import HostManager
    from canbus.master.hostconfig import HostConfig
    from canbus.zenoh.publisher import ZenohPublisher
    from skin.commands.common.hostrecord import HostRecording

POLL_S = 0.1
SHOWN_ON_STDOUT = ("canbus.master.patchstate", "canbus.master.discovery")
"""The host's loggers of patch states and unknown nodes: their lines go to stdout, once."""


def _follow(host: HostManager, deadline: float | None, status_every: float | None) -> None:
    """Print a status line every ``status_every`` seconds until ``deadline``, Ctrl-C, or a
    bus that is gone for good."""
    tick = threading.Event()
    status = _Status(host)
    started = time.monotonic()
    next_status = None if status_every is None else started + status_every
    while deadline is None or time.monotonic() < deadline:
        if host.bus_gone() is not None:
            return
        now = time.monotonic()
        if next_status is not None and status_every is not None and now >= next_status:
            print(status.line(), flush=True)
            next_status += status_every
        left = POLL_S if deadline is None else min(POLL_S, deadline - now)
        tick.wait(max(0.0, left))


class _Status:
    """A health line: patches operational, sample rate, incomplete share, bus load."""

    def __init__(self, host: HostManager) -> None:
        self.host = host
        self.last = (time.monotonic(), 0, 0)
        self.wires = {name: _wire(link.bus) for name, link in host.links.items()}

    def line(self) -> str:
        host = self.host
        health = host.health()
        operational = sum(h.state == "operational" for h in health.values())
        stats = host.stats()
        now = time.monotonic()
        then, samples, incomplete = self.last
        span = max(now - then, 1e-9)
        new = stats["samples"] - samples
        share = 100.0 * (stats["incomplete_samples"] - incomplete) / new if new else 0.0
        self.last = (now, stats["samples"], stats["incomplete_samples"])
        loads = []
        for name, link in host.links.items():
            wire, before = _wire(link.bus), self.wires.get(name)
            if wire is not None and before is not None:
                loads.append(f"{name} {wire.load_since(before):.0f} %")
            self.wires[name] = wire
        load = f", bus load {', '.join(loads)}" if loads else ""
        return (f"{time.strftime('%H:%M:%S')} status: {operational}/{len(health)} patches "
                f"operational, {new / span:.0f} samples/s, {share:.1f} % incomplete"
                f"{load}")


def _wire(bus: can.BusABC) -> Any:
    stats = getattr(bus, "wire_stats", None)
    return stats() if callable(stats) else None


def _run(args: argparse.Namespace) -> int:
    from canbus.master.hostconfig import load_host_config
    from skin.commands.common.configpath import find_config
    from skin.commands.common.cpu import pinned
    from skin.commands.common.hostbus import resolve
    from skin.commands.common.realtime import realtime
    from skin.errors import ConfigError
    from skin.inputs.outputs import check_writable

    if args.status_every is not None and not args.status_every > 0:
        raise ConfigError("--status-every", f"must be > 0 s, got {args.status_every}")
    if args.json:
        check_writable(args.json)  # now, not after the run
    if args.record:
        from canbus.tools.recorder import recording_format

        if recording_format(args.record) == ".mcap":
            from canbus.tools.mcap_messages import require_mcap

            require_mcap()
    config = resolve(load_host_config(find_config(args.config)), args)
    if args.zenoh or (config.zenoh is not None and config.zenoh.enabled):
        from canbus.master.zenoh_settings import require_zenoh

        require_zenoh("--zenoh" if args.zenoh else "zenoh")
    with pinned(args.cpu), realtime(args.realtime):  # before any thread starts
        return _run_host(args, config)


def _run_host(args: argparse.Namespace, config: HostConfig) -> int:
    from contextlib import ExitStack

    from canbus.master.host import HostManager
    from skin.commands.common.hostbus import describe, open_all
    from skin.commands.common.signals import until_stopped

    started = time.monotonic()
    with ExitStack() as stack:
        buses = open_all(config, stack, rcvbuf=args.rcvbuf)
        host = HostManager(buses, config, listen_only=True if args.listen_only else None)
        gc.collect()  # the object dictionaries are long-lived: keep the collector off them
        gc.freeze()
        stack.callback(gc.unfreeze)
        stack.enter_context(_host_events_shown())
        stack.enter_context(_lines_on_stdout())
        publisher, recorded = _beside(stack, args, config, host)
        # A stop (Ctrl-C, SIGTERM, SIGHUP) from the line that says how to stop on ends the
        # run as --seconds does: the summary and --json follow.
        with until_stopped() as stopped:
            _print_banner(host.listen_only, config, describe(config))
            # --seconds S: S seconds once started; a start still going then (a long scan,
            # set-ups waiting out SDO time-outs) is cut short at S.
            with _stops_at(args.seconds, host) as cut:
                host.start()
            try:
                if not cut.is_set():
                    _hint_if_nobody_answered(host, config)
                    _follow(host, None if args.seconds is None else
                            time.monotonic() + args.seconds, args.status_every)
            finally:
                host.stop()
        if stopped.signal is not None:
            print(f"stopped by {stopped.signal}", flush=True)
        stats = host.stats()
        health = host.health()
        buses_stats = host.bus_stats()
        gone = host.bus_gone()
    elapsed = time.monotonic() - started
    _print_summary(host.listen_only, stats, elapsed, publisher)
    if recorded is not None:
        print(recorded.summary(args.record))
    if args.json:
        record: dict[str, Any] = {
            "config": config.source, "listen_only": host.listen_only,
            "seconds": round(elapsed, 3), "stopped_by": stopped.signal, "stats": stats,
            "steady_complete_pct": steady_complete_pct(stats),
            "buses": buses_stats,
            "patches": {str(n): h.as_json() for n, h in health.items()},
            "unknown_nodes": sorted(host.unknown_nodes),
            "bus_gone": gone,
            "zenoh": None if publisher is None else publisher.counters(),
            "recording": None if recorded is None else recorded.as_json(args.record),
        }
        _write_json(args.json, record)
    if gone is not None:
        from skin.errors import BusError

        raise BusError(f"{gone}: the host cannot hear its patches")
    return 0


class _ContactLines:
    """Prints a line whenever a contact on the robot's links begins or the patches it rests
    on change (docs/robot.md): the host's force callback only queues the frame, a thread
    of its own groups them into cycles and prints; it ends after the host stops."""

    def __init__(self, host: HostManager) -> None:
        import queue

        self.host = host
        self.queue: queue.SimpleQueue[ForceFrame | None] = queue.SimpleQueue()
        self.thread = threading.Thread(target=self._follow, name="contacts", daemon=True)

    def __enter__(self) -> _ContactLines:
        self.thread.start()
        self.host.on_forces(self.queue.put)
        return self

    def __exit__(self, *exc: object) -> None:
        self.host.remove_callback(self.queue.put)
        self.queue.put(None)
        self.thread.join()

    def _frames(self) -> Iterator[ForceFrame]:
        while (frame := self.queue.get()) is not None:
            yield frame

    def _follow(self) -> None:
        from canbus.master.robot import robot_contacts

        before: set[tuple[str, tuple[int, ...]]] = set()
        for _, contacts in robot_contacts(self._frames()):
            now = {(c.link, c.patches) for c in contacts}
            for c in contacts:
                if (c.link, c.patches) not in before:
                    x, y, z = (1e3 * c.point_m).tolist()
                    fx, fy, fz = c.force_N.tolist()
                    print(f"{time.strftime('%H:%M:%S')} contact on {c.link} (patches "
                          f"{'+'.join(map(str, c.patches))}): point ({x:.1f}, {y:.1f}, "
                          f"{z:.1f}) mm, force ({fx:+.2f}, {fy:+.2f}, {fz:+.2f}) N",
                          flush=True)
            before = now


def _beside(stack: Any, args: argparse.Namespace, config: HostConfig, host: HostManager
            ) -> tuple[ZenohPublisher | None, HostRecording | None]:
    """The Zenoh publisher and the ``--record`` recording, each closed after the host
    stops (its last samples go out, its last frames are in the file)."""
    publisher = _zenoh_publisher(host, config, args)
    if publisher is not None:
        stack.enter_context(publisher)
    if args.contacts:
        stack.enter_context(_ContactLines(host))
    if not args.record:
        return publisher, None
    from skin.commands.common.hostrecord import recording

    recorded: HostRecording = stack.enter_context(
        recording(args.record, config, host, args.rcvbuf))
    return publisher, recorded


def _print_summary(listen_only: bool, stats: dict[str, int], elapsed: float,
                   publisher: ZenohPublisher | None) -> None:
    verb = "decoded" if listen_only else "published"
    print(steady_state_line(stats))
    print(f"{verb} {stats['samples']} samples ({stats['complete_samples']} complete, "
          f"{stats['incomplete_samples']} incomplete) in {elapsed:.1f} s; frames in "
          f"{stats['frames_in']}, out {stats['frames_out']}, late {stats['late_frames']}, "
          f"duplicate {stats['duplicate_frames']}")
    if publisher is not None:
        z = publisher.counters()
        print(f"zenoh: {z['sent']} samples sent on {publisher.settings.prefix}/"
              f"{publisher.host_name}/**, {z['dropped']} dropped, {z['events_sent']} events")


def steady_complete_pct(stats: dict[str, int]) -> float | None:
    """The steady state's complete share in %: samples of the cycles from the first one
    with every patch operational (None: no such cycle, the set-up never ended)."""
    steady = stats["steady_samples"]
    return None if not steady else round(100.0 * stats["steady_complete_samples"] / steady, 3)


def steady_state_line(stats: dict[str, int]) -> str:
    setup = stats["samples"] - stats["steady_samples"]
    pct = steady_complete_pct(stats)
    if pct is None:
        return (f"steady state: none (not every patch became operational); {setup} samples "
                "during set-up")
    incomplete = stats["steady_samples"] - stats["steady_complete_samples"]
    return (f"steady state (every patch operational): {stats['steady_samples']} samples, "
            f"{pct:.2f} % complete ({incomplete} incomplete); {setup} samples during set-up")


def _write_json(path: str, record: dict[str, Any]) -> None:
    from skin.atomic import atomic_write

    with atomic_write(path) as handle:
        handle.write(json.dumps(record, indent=2).encode() + b"\n")


def _print_banner(listen_only: bool, config: HostConfig, bus_text: str) -> None:
    n = len(config.patches)
    patches = f"{n} patch{'es' if n > 1 else ''} on {bus_text}"
    if listen_only:
        print(f"host (listen-only): {patches}, following the SYNCs on the bus, "
              "decoding; nothing is sent; Ctrl-C stops", flush=True)
    else:
        forces = ", ".join(f"{p.node_id}->{p.force_node}" for p in config.patches)
        print(f"host: {patches}, SYNC {sync_text(config)}, forces published as "
              f"nodes {forces}; Ctrl-C stops", flush=True)


def _zenoh_publisher(host: HostManager, config: HostConfig,
                     args: argparse.Namespace) -> ZenohPublisher | None:
    """The host's publisher on Zenoh when the config's [zenoh] or --zenoh asks for one."""
    if not (args.zenoh or (config.zenoh is not None and config.zenoh.enabled)):
        return None
    from dataclasses import replace

    from canbus.master.zenoh_settings import ZenohSettings
    from canbus.zenoh.publisher import ZenohPublisher

    settings = replace(config.zenoh or ZenohSettings(), enabled=True)
    publisher = ZenohPublisher(host, settings)
    listen = ", ".join(settings.listen_endpoints()) or "nothing"
    connect = ", ".join(settings.connect_endpoints())
    print(f"zenoh: publishing on {settings.prefix}/{publisher.host_name}/** ({settings.mode}, "
          f"listen {listen}{', connect ' + connect if connect else ''})", flush=True)
    return publisher


def sync_text(config: HostConfig) -> str:
    if config.sync == "external":
        return "from another master (sync = external)"
    return f"every {config.sync_period_ms:g} ms"


@contextlib.contextmanager
def _host_events_shown() -> Iterator[None]:
    """The host's own log lines (state changes, lost patches, EMCYs, invalid taxels) at
    INFO, shown whenever the command's own progress lines are (the default)."""
    host = logging.getLogger("canbus.master")
    before = host.level
    if logging.getLogger("skin.commands").getEffectiveLevel() <= logging.INFO:
        host.setLevel(min(logging.INFO, host.getEffectiveLevel()))
    try:
        yield
    finally:
        host.setLevel(before)


@contextlib.contextmanager
def _lines_on_stdout() -> Iterator[None]:
    """The host's lines of patch states and unknown nodes (:data:`SHOWN_ON_STDOUT`) on
    stdout as ``patch 1: operational``: the log record is the one path, not also a line
    on stderr."""
    handler = _StdoutHandler()
    saved = []
    for name in SHOWN_ON_STDOUT:
        logger = logging.getLogger(name)
        saved.append((logger, logger.level, logger.propagate))
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)
        logger.propagate = False
    try:
        yield
    finally:
        for logger, level, propagate in saved:
            logger.removeHandler(handler)
            logger.setLevel(level)
            logger.propagate = propagate


class _StdoutHandler(logging.Handler):
    """The record's message alone, on whatever ``sys.stdout`` is at the time."""

    def emit(self, record: logging.LogRecord) -> None:
        import sys

        try:
            print(record.getMessage(), file=sys.stdout, flush=True)
        except Exception:
            self.handleError(record)


@contextlib.contextmanager
def _stops_at(seconds: float | None, host: HostManager) -> Iterator[threading.Event]:
    """Stop the host in ``seconds`` if the block (its start) still runs then; the event
    yielded is set if it did."""
    cut = threading.Event()

    def stop() -> None:
        cut.set()
        host.stop()

    timer = None
    if seconds is not None:
        timer = threading.Timer(max(0.0, seconds), stop)
        timer.daemon = True
        timer.start()
    try:
        yield cut
    finally:
        if timer is not None:
            timer.cancel()
            if cut.is_set():
                timer.join()  # its stop() has run: the host is stopped


def _hint_if_nobody_answered(host: HostManager, config: HostConfig) -> None:
    """One line when no configured patch answered the scan: the bus, and what to check."""
    if host.listen_only or not config.scan:
        return
    if all(h.state == "absent" for h in host.health().values()):
        from skin.commands.common.hostbus import describe

        print(f"no patch answered on {describe(config)} within {config.scan_ms} ms: check "
              "that the patches are powered and on this bus (interface, channel, bit rate); "
              "they are configured when they boot", flush=True)


def add_subparser(subparsers: Any) -> None:
    from skin.commands.common.busargs import add_rcvbuf_argument
    from skin.commands.common.cpu import add_cpu_argument
    from skin.commands.common.realtime import DEFAULT_PRIORITY
    from skin.commands.common.realtime import priority as realtime_priority

    parser = subparsers.add_parser("run", help="the host manager on a bus (CONFIG.toml)")
    parser.add_argument("config", metavar="CONFIG", nargs="?", default=None,
                        help="host config (see examples/host.toml); default: the first of "
                             "$SKIN_HOST_CONFIG, ./host.toml, ~/.config/canskin/host.toml, "
                             "/etc/canskin/host.toml")
    parser.add_argument("--seconds", type=argtypes.seconds, default=None, metavar="S",
                        help="run S seconds once started; a start still going at S (a "
                             "long scan, set-ups waiting on SDO) is cut short there "
                             "(default: run until Ctrl-C)")
    parser.add_argument("--listen-only", action="store_true",
                        help="decode what another master runs (or `skin replay` sends) and "
                             "transmit nothing: no scan, SDO, NMT, SYNC or force node "
                             "(default: host.listen_only of the config)")
    parser.add_argument("--json", type=argtypes.output_file, metavar="FILE",
                        help="write the run's figures as JSON")
    parser.add_argument("--status-every", type=argtypes.seconds, default=None, metavar="S",
                        help="print a health line every S seconds")
    parser.add_argument("--contacts", action="store_true",
                        help="print a line whenever a contact on the robot's links begins: "
                             "link, patches, point and force in the link's frame "
                             "(patches placed on links, docs/robot.md)")
    parser.add_argument("--zenoh", action="store_true",
                        help="publish every force sample, state change, EMCY and the "
                             "statistics on Zenoh (the config's [zenoh] table, else "
                             "defaults: listen on tcp/127.0.0.1:7447; docs/zenoh.md)")
    parser.add_argument("--record", type=argtypes.output_file, metavar="FILE",
                        help="record every frame on the host's buses (its own included) to "
                             "FILE: .log, .asc, .blf, .pcap, or .mcap, which also holds every "
                             "force sample and contact summary published (docs/mcap.md)")
    add_cpu_argument(parser, default="all")
    parser.add_argument("--realtime", type=realtime_priority, nargs="?", const=DEFAULT_PRIORITY,
                        default=None, metavar="PRIO",
                        help="run every thread under SCHED_FIFO at PRIO (1..99, default "
                             f"{DEFAULT_PRIORITY}), ahead of normal processes; where not "
                             "permitted, one warning and normal priority (docs/host.md)")
    add_rcvbuf_argument(parser)
    argtypes.add_bus_arguments(parser)
    parser.set_defaults(func=_run, runs_until_stopped=True)
