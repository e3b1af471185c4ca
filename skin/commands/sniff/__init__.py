"""``skin sniff``: a live, EDS-aware view of a CANopen bus; ``--record`` keeps every frame.

Frames go from python-can's Notifier thread to the recorder's queue first, then to the
sniffer's counters; neither waits for the view. The live view (rich) redraws at most
``--refresh`` times a second from a snapshot of the counters, so when it cannot keep up
it redraws less often (the redraws it skipped are counted) and never costs a frame.
``--view lines`` prints one line per frame through a bounded queue (lines it had to drop
are counted); ``--view none`` prints only the summary.

Ctrl-C, SIGTERM and SIGHUP end a capture normally: the recording is closed complete, the
summary printed, ``--json`` written, exit status 0. The recording is written as it goes
(``canbus.tools.recorder``): a capture killed outright keeps every frame but the last
0.1 s.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import sys
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from skin.commands.common import argtypes

if TYPE_CHECKING:
    from pathlib import Path

    import can

    from canbus.tools.recorder import Recorder
    from canbus.tools.snapshot import Snapshot
    from canbus.tools.sniffer import FrameFilter, Sniffer

from skin.commands.sniff.view import LinePrinter, ViewStats, render, summary_lines

SERVICES = ("nmt", "sync", "emcy", "time", "pdo", "sdo", "heartbeat", "lss", "error", "unknown")
logger = logging.getLogger(__name__)
_SWITCH_S = 0.0005  # the longest a busy thread keeps the GIL from the receive thread
_DRAW_SHARE = 0.2  # the live view draws at most this share of the time
_TICK_S = 0.05


@dataclass
class Capture:
    """How a capture ended."""

    seconds: float
    cpu_s: float  # this process, all threads
    saved: Path | None
    files: list[Path]
    recorded: int
    error: BaseException | None
    stopped_by: str | None
    receive: dict[str, Any] | None = None  # what receiving survived (canbus.busio)


def _sniff(args: argparse.Namespace) -> int:
    from canbus.tools.attribution import Attribution
    from canbus.tools.pdo_dictionary import Dictionary, parse_assignment
    from canbus.tools.recorder import check_channel_name, recording_format
    from canbus.tools.services import ServiceDecoder
    from canbus.tools.sniffer import FrameFilter, Sniffer
    from skin.commands.common.busopen import open_command_bus
    from skin.commands.common.logs import held_back
    from skin.commands.common.tool_config import config_nodes, tool_config
    from skin.errors import BusError, ConfigError

    if args.record:
        recording_format(args.record)  # refused before the bus is opened
    elif args.rotate_size is not None or args.rotate_seconds is not None:
        raise ConfigError("--rotate-size/--rotate-seconds", "rotate a recording: give "
                          "--record FILE too")
    if args.channel_name is not None:
        check_channel_name(args.channel_name)
    for name in ("seconds", "refresh", "rotate_seconds"):
        value = getattr(args, name)
        if value is not None and not value > 0:
            raise ConfigError(f"--{name.replace('_', '-')}", f"must be positive, got {value}")
    assignments: dict[int, str | None] = {}
    with held_back("canopen"):
        for text in args.eds:
            assignments |= parse_assignment(text)
    config = tool_config(args)
    decoder = ServiceDecoder(attribution=Attribution(Dictionary(assignments),
                                                     config_nodes(config, args)))
    shown = FrameFilter(args.node, args.service)
    view = args.view or ("live" if sys.stdout.isatty() else "lines")
    stats = ViewStats()
    printer = LinePrinter(decoder, shown, sys.stdout, stats) if view == "lines" else None
    sniffer = Sniffer(decoder, bitrate=getattr(args, "bitrate", None) or 1_000_000,
                      data_bitrate=getattr(args, "data_bitrate", None),
                      on_frame=printer.on_frame if printer is not None else None,
                      answer_orders=None if config is None else {
                          p.node_id: p.answer_order for p in config.patches})
    switch = sys.getswitchinterval()
    try:
        sys.setswitchinterval(min(switch, _SWITCH_S))
        bus, args.described = open_command_bus(  # lines mode: stdout is the frames
            args, command="skin sniff", config=config, sends=args.ask_by_sdo,
            out=sys.stderr if view == "lines" else sys.stdout, resilient=True,
            rcvbuf=args.rcvbuf)
        with bus:  # what recv raises is survived; a bus that keeps failing is opened again
            capture = _capture(bus, sniffer, shown, printer, stats, view, args)
            capture.receive = bus.stats.as_dict()
    finally:
        sys.setswitchinterval(switch)
    _report(sniffer.snapshot(), capture, stats, view, args,
            sniffer.decoder.attribution.silent_nodes())
    if capture.error is not None:
        raise BusError(f"receiving stopped: {capture.error}") from capture.error
    return 0


def _capture(bus: can.BusABC, sniffer: Sniffer, shown: FrameFilter,
             printer: LinePrinter | None, stats: ViewStats, view: str,
             args: argparse.Namespace) -> Capture:
    """Receive until the end (Ctrl-C, SIGTERM, SIGHUP included); the recording is closed
    complete whatever ends it."""
    from canbus.receiveloop import ReceiveLoop
    from canbus.tools.recorder import Recorder, log_channel_name
    from skin.commands.common.signals import until_stopped
    from skin.commands.common.tool_config import asking

    name = args.channel_name or log_channel_name(getattr(args, "channel", None))
    header = f"skin sniff {args.described}" + (f" → {args.record}" if args.record else "")
    started, cpu = time.monotonic(), time.process_time()
    recorder: Recorder | None = None
    notifier: ReceiveLoop | None = None
    try:
        with until_stopped() as stopped, contextlib.ExitStack() as stack:  # Ctrl-C: the end
            if args.record:
                recorder = Recorder(args.record, channel=name, rotate_bytes=args.rotate_size,
                                    rotate_s=args.rotate_seconds)
            listeners: list[can.Listener] = [sniffer] if recorder is None else \
                [recorder, sniffer]
            asker = asking(bus, sniffer.decoder.attribution, args)
            if asker is not None:
                listeners.append(asker.listener)
            notifier = ReceiveLoop(bus, listeners, timeout=_TICK_S, name=args.described)
            if asker is not None:
                stack.callback(asker.stop)
                asker.start()
            if printer is not None:
                printer.start()
            # receiving from here on; beside the bus's line (stderr when stdout is the frames)
            print(f"capturing {header}; Ctrl-C stops", flush=True,
                  file=sys.stderr if view == "lines" else sys.stdout)
            _watch(notifier, recorder, printer, sniffer, shown, stats, view, header, args,
                   started)
    finally:
        try:
            if notifier is not None:
                notifier.stop()  # also stops the recorder: written out, synced, closed
        finally:
            if printer is not None:
                printer.stop()
            if recorder is not None:
                with contextlib.suppress(Exception):  # an error is already on its way
                    recorder.stop()  # keeps what was received: a recording is a stream
    seconds, cpu = time.monotonic() - started, time.process_time() - cpu
    return Capture(seconds, cpu, recorder.saved if recorder else None,
                   recorder.files if recorder else [], recorder.written if recorder else 0,
                   None if notifier is None else notifier.exception, stopped.signal)


def _report(snap: Snapshot, capture: Capture, stats: ViewStats, view: str,
            args: argparse.Namespace, silent: list[int]) -> None:
    from skin.atomic import atomic_write

    out = sys.stderr if view == "lines" else sys.stdout  # lines mode: stdout is the frames
    for line in summary_lines(snap, capture.seconds, stats):
        print(line, file=out)
    if silent and snap.anomalies.unattributed_frames:
        print(f"node{'s' if len(silent) > 1 else ''} {', '.join(map(str, silent))}: heartbeat "
              "seen, no PDO known to be theirs (remapped where this bus did not show it, or "
              "not sending)", file=out)
    if capture.saved is not None:
        where = str(capture.saved) if len(capture.files) == 1 else \
            f"{capture.files[0]} .. {capture.files[-1]} ({len(capture.files)} files)"
        print(f"recorded {capture.recorded:,} frames to {where}", file=out)
    if args.json:
        record = snap.to_dict(capture.seconds) | {
            "cpu_share": capture.cpu_s / max(capture.seconds, 1e-9),
            "recording": None if capture.saved is None else
            {"path": str(capture.saved), "frames": capture.recorded,
             "files": [str(p) for p in capture.files]},
            "stopped_by": capture.stopped_by, "silent_nodes": silent,
            "receive": capture.receive,
            "view": {"mode": view, "redraws": stats.redraws,
                     "redraws_skipped": stats.redraws_skipped, "lines": stats.lines,
                     "lines_dropped": stats.lines_dropped}}
        with atomic_write(args.json) as handle:
            handle.write(json.dumps(record, indent=2).encode() + b"\n")


def _watch(notifier: can.Notifier, recorder: Recorder | None, printer: LinePrinter | None,
           sniffer: Sniffer, shown: FrameFilter, stats: ViewStats, view: str, header: str,
           args: argparse.Namespace, started: float) -> None:
    """Wait for the end (seconds, Ctrl-C, a dead receive thread or recorder), redrawing if
    live: at most ``--refresh`` times a second, skipping the redraws that did not fit."""
    deadline = None if args.seconds is None else started + args.seconds
    period = 1.0 / args.refresh
    decoder = sniffer.decoder

    def done() -> bool:
        return notifier.exception is not None or \
            (recorder is not None and recorder.error is not None) or \
            (printer is not None and printer.broken) or \
            (deadline is not None and time.monotonic() >= deadline)

    if view != "live":
        while not done():
            time.sleep(_TICK_S if deadline is None else
                       max(0.0, min(_TICK_S, deadline - time.monotonic())))
        return
    from rich.console import Console
    from rich.live import Live

    console = Console()
    rows = max(4, console.size.height - 16)
    due = started
    with Live(console=console, auto_refresh=False, transient=False) as live:
        while not done():
            now = time.monotonic()
            if now < due:
                time.sleep(min(due - now, _TICK_S))
                continue
            live.update(render(sniffer.snapshot(), decoder, shown, stats, header,
                               now - started, rows), refresh=True)
            stats.redraws += 1
            # A redraw holds the GIL, which the receive thread needs: draw for a fixed
            # share of the time at most, so a slow view skips redraws, never frames.
            after = time.monotonic()
            following = max(due + period, after + (after - now) / _DRAW_SHARE)
            stats.redraws_skipped += int((following - due) / period + 1e-9) - 1
            due = following
        live.update(render(sniffer.snapshot(), decoder, shown, stats, header,
                           time.monotonic() - started, rows), refresh=True)




def add_subparser(subparsers: Any) -> None:
    from skin.commands.common.busargs import add_rcvbuf_argument
    from skin.commands.common.tool_config import add_config_arguments

    parser = subparsers.add_parser(
        "sniff", help="live, EDS-aware bus view; --record to .log/.asc/.blf/.pcap/.mcap",
        description="Show every CANopen service on a bus, decoded with the EDS files, with "
                    "per COB-ID rates, bus load and anomaly counters; record every frame.")
    parser.add_argument("--eds", action="append", default=[], metavar="NODE=FILE",
                        help="decode node NODE (or FIRST-LAST) with FILE (a path or a shipped "
                             "EDS name); default: 1..64 skin-patch, 65..127 skin-forces")
    parser.add_argument("--node", action="append", type=argtypes.node_id, default=[], metavar="N",
                        help="show only node N (repeatable); statistics still see every frame")
    parser.add_argument("--service", action="append", choices=SERVICES, default=[],
                        help="show only this service (repeatable)")
    parser.add_argument("--record", type=argtypes.output_file, metavar="FILE",
                        help="record every frame to FILE: .log (candump -L), .asc, .blf, "
                             ".pcap, .mcap (ROS 2 messages, docs/mcap.md)")
    parser.add_argument("--rotate-size", type=argtypes.rotate_size, default=None, metavar="BYTES",
                        help="go on in a new file (run.001.log, run.002.log, ...) once one "
                             "reaches BYTES (k, M, G: powers of 1024); each file is a whole "
                             "recording")
    parser.add_argument("--rotate-seconds", type=argtypes.seconds, default=None, metavar="S",
                        help="go on in a new file every S seconds")
    parser.add_argument("--channel-name", default=None, metavar="NAME",
                        help="the interface name a .log recording gives every frame, as "
                             "log2asc and canplayer expect it (default: the bus's channel "
                             "if it is an interface name, else can0)")
    parser.add_argument("--seconds", type=argtypes.seconds, default=None, metavar="S",
                        help="stop after S seconds (default: at Ctrl-C)")
    parser.add_argument("--view", choices=("live", "lines", "none"), default=None,
                        help="live table, one line per frame, or summary only "
                             "(default: live on a terminal, else lines)")
    parser.add_argument("--refresh",
                        type=argtypes.number("rate", above=0.0, high=1000.0, unit="Hz"),
                        default=4.0, metavar="HZ",
                        help="live view redraws per second at most (default 4)")
    add_rcvbuf_argument(parser)
    parser.add_argument("--json", type=argtypes.output_file, metavar="FILE",
                        help="write the summary as JSON")
    add_config_arguments(parser)
    argtypes.add_bus_arguments(parser, filter_arg=True)
    parser.set_defaults(func=_sniff, runs_until_stopped=True)
