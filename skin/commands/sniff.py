"""``skin sniff``: a live, EDS-aware view of a CANopen bus; ``--record`` keeps every frame.

Frames go from python-can's Notifier thread to the recorder's queue first, then to the
sniffer's counters; neither waits for the view. The live view (rich) redraws at most
``--refresh`` times a second from a snapshot of the counters, so when it cannot keep up
it redraws less often (the redraws it skipped are counted) and never costs a frame.
``--view lines`` prints one line per frame through a bounded queue (lines it had to drop
are counted); ``--view none`` prints only the summary.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TextIO

if TYPE_CHECKING:
    from pathlib import Path

    import can
    from rich.console import RenderableType

    from canbus.recorder import Recorder
    from canbus.services import Decoded, Route, ServiceDecoder
    from canbus.sniffer import FrameFilter, Snapshot, Sniffer

SERVICES = ("nmt", "sync", "emcy", "time", "pdo", "sdo", "heartbeat", "lss", "error", "unknown")
_LINE_QUEUE = 100_000
_LINES_POLL_S = 0.02
_RCVBUF = 4 * 1024 * 1024
_SWITCH_S = 0.0005  # the longest a busy thread keeps the GIL from the receive thread
_DRAW_SHARE = 0.2  # the live view draws at most this share of the time
_TICK_S = 0.05


@dataclass
class ViewStats:
    redraws: int = 0
    redraws_skipped: int = 0
    lines: int = 0
    lines_dropped: int = 0
    rates: dict[tuple[int, bool], tuple[int, float]] = field(default_factory=dict)


class LinePrinter:
    """One line per shown frame, written in batches by a thread of its own.

    The receive thread only appends to a bounded deque (a full one drops the line and
    counts it); every 20 ms the printer formats what arrived, PDOs decoded per COB-ID in
    one numpy batch, and writes it in one call.
    """

    def __init__(self, decoder: ServiceDecoder, shown: FrameFilter, out: TextIO,
                 stats: ViewStats) -> None:
        self.decoder, self.shown, self.out, self.stats = decoder, shown, out, stats
        self._pending: deque[tuple[can.Message, Route, Decoded | None]] = deque()
        self._stopping = threading.Event()
        self.broken = False
        self._thread = threading.Thread(target=self._print, name="sniff-lines", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def on_frame(self, msg: can.Message, where: Route, decoded: Decoded | None) -> None:
        if not self.shown(where):
            return
        if len(self._pending) >= _LINE_QUEUE:
            self.stats.lines_dropped += 1
        else:
            self._pending.append((msg, where, decoded))

    def _print(self) -> None:
        pending = self._pending
        try:
            while True:
                stopping = self._stopping.wait(_LINES_POLL_S)
                while pending:
                    batch = [pending.popleft() for _ in range(min(len(pending), 4096))]
                    self.out.write("".join(self.format(batch)))
                    self.stats.lines += len(batch)
                self.out.flush()
                if stopping:
                    return
        except BrokenPipeError:  # `skin sniff | head`: the reader is gone, so is the capture
            self.broken = True
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, self.out.fileno())  # no second error when Python flushes stdout
            os.close(devnull)

    def format(self, batch: list[tuple[can.Message, Route, Decoded | None]]) -> list[str]:
        from canbus.services import Service

        texts = [d.text if d is not None else None for _, _, d in batch]
        labels = [d.label if d is not None else w.label for _, w, d in batch]
        groups: dict[int, list[int]] = {}
        for k, (msg, where, decoded) in enumerate(batch):
            if decoded is None and where.service is Service.PDO:
                groups.setdefault(msg.arbitration_id, []).append(k)
        for cob_id, ks in groups.items():
            node = batch[ks[0]][1].node
            view = self.decoder.dictionary.view(node) if node is not None else None
            described = self.decoder.describe_pdos(
                cob_id, [bytes(batch[k][0].data) for k in ks], view)
            for k, pdo_text in zip(ks, described, strict=True):
                texts[k] = pdo_text
                labels[k] = self.decoder.pdo_label(batch[k][0], batch[k][1])
        lines = []
        for (msg, where, _), maybe_text, label in zip(batch, texts, labels, strict=True):
            text = maybe_text
            if text is None:
                decoded = self.decoder.decode(msg, where)
                text, label = decoded.text, decoded.label
            data = msg.data.hex(" ") if not msg.is_remote_frame else f"R{msg.dlc}"
            lines.append(f"{msg.timestamp:.6f} {_cob(msg)} [{msg.dlc}] {data:<23} "
                         f"{where.service:<9} {self.decoder.node_label(where.node):<10} "
                         f"{label:<9} {text}\n")
        return lines

    def stop(self) -> None:
        self._stopping.set()
        if self._thread.is_alive():
            self._thread.join()


def _cob(msg: can.Message) -> str:
    return f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"


def render(snap: Snapshot, decoder: ServiceDecoder, shown: FrameFilter, stats: ViewStats,
           header: str, elapsed: float, rows: int) -> RenderableType:
    """The live view of one snapshot: header, COB-ID table, anomalies, recent events."""
    from rich.console import Group
    from rich.text import Text

    best, worst = snap.load_pct(elapsed)
    title = Text.assemble((header, "bold"), f"  {elapsed:6.1f} s  {snap.frames:,} frames  "
                          f"load {best:.1f}–{worst:.1f} %  redraws {stats.redraws} "
                          f"(skipped {stats.redraws_skipped})")
    a = snap.anomalies
    anomalies = Text(f"missed SYNC {a.missed_sync}  incomplete samples {a.incomplete_samples}"
                     f"/{a.incomplete_samples + a.complete_samples}  heartbeat gaps "
                     f"{a.heartbeat_gaps}  unknown {a.unknown_frames} "
                     f"({len(a.unknown_cob_ids)} ids)  error frames {a.error_frames}",
                     style="yellow" if any((a.missed_sync, a.incomplete_samples,
                                            a.heartbeat_gaps, a.unknown_frames,
                                            a.error_frames)) else "green")
    states = "  ".join(f"{decoder.node_label(n)}: {s}" for n, s in sorted(snap.states.items()))
    start = snap.first or 0.0
    events = [Text(f"{e.timestamp - start:9.3f} {e.cob_id:03X} {e.label:<9} "
                   f"{decoder.node_label(e.node):<10} {e.text}", no_wrap=True,
                   overflow="ellipsis")
              for e in [e for e in snap.events if shown(e.route)][-8:]]
    return Group(title, _table(snap, decoder, shown, stats, rows), anomalies,
                 Text(states or "no heartbeats yet", style="dim"),
                 Text("events (s since the first frame)", style="bold"), *events)


def _table(snap: Snapshot, decoder: ServiceDecoder, shown: FrameFilter, stats: ViewStats,
           rows: int) -> RenderableType:
    """One row per shown COB-ID: counts, rate since the last redraw, Δt, the last value."""
    from rich.table import Table

    table = Table(expand=True, box=None, header_style="bold", pad_edge=False)
    for name, justify in (("COB-ID", "left"), ("service", "left"), ("node", "left"),
                          ("", "left"), ("frames", "right"), ("Hz", "right"),
                          ("Δt ms", "right"), ("min/max ms", "right"), ("last", "left")):
        table.add_column(name, justify=justify, no_wrap=name != "last",  # type: ignore[arg-type]
                         overflow="ellipsis")
    now = time.monotonic()
    shown_rows = [r for r in snap.rows if shown(r.route)]
    for row in shown_rows[:rows]:
        key = (row.cob_id, row.extended)
        if key in stats.rates and now > stats.rates[key][1]:
            count, then = stats.rates[key]
            hz = (row.count - count) / (now - then)
        else:
            hz = row.rate_hz
        stats.rates[key] = (row.count, now)
        last = row.last_text
        if row.last_msg is not None and not last:
            last = decoder.decode(row.last_msg, row.route).text
        timing = (f"{1e3 * row.dt_last_s:.2f}",
                  f"{1e3 * row.dt_min_s:.1f}/{1e3 * row.dt_max_s:.1f}") if row.count > 1 \
            else ("", "")
        label = decoder.pdo_label(row.last_msg, row.route) \
            if row.last_msg is not None and row.service == "pdo" else row.label
        table.add_row(f"{row.cob_id:03X}", str(row.service), decoder.node_label(row.node),
                      label, f"{row.count:,}", f"{hz:.1f}", *timing, last)
    if len(shown_rows) > rows:
        table.add_row("…", f"{len(shown_rows) - rows} more", "", "", "", "", "", "", "")
    return table


def summary_lines(snap: Snapshot, seconds: float, stats: ViewStats) -> list[str]:
    best, worst = snap.load_pct(seconds)
    a = snap.anomalies
    services = ", ".join(f"{k} {v:,}" for k, v in sorted(snap.by_service.items()))
    unknown = " ".join(f"0x{c:X}" for c in a.unknown_cob_ids[:16])
    return [
        f"{snap.frames:,} frames in {seconds:.1f} s ({snap.frames / max(seconds, 1e-9):,.0f} "
        f"frames/s), bus load {best:.1f} % (no stuffing) to {worst:.1f} % (worst case) of "
        f"{snap.bitrate:,} bit/s",
        f"by service: {services or 'none'}",
        f"anomalies: missed SYNC {a.missed_sync}, incomplete samples {a.incomplete_samples} "
        f"of {a.incomplete_samples + a.complete_samples}, heartbeat gaps {a.heartbeat_gaps}, "
        f"unknown frames {a.unknown_frames}{f' ({unknown})' if unknown else ''}, "
        f"error frames {a.error_frames}",
        f"view: {stats.redraws} redraws ({stats.redraws_skipped} skipped), "
        f"{stats.lines:,} lines ({stats.lines_dropped:,} dropped)",
    ]


@dataclass
class Capture:
    """How a capture ended."""

    seconds: float
    cpu_s: float  # this process, all threads
    saved: Path | None
    recorded: int
    error: BaseException | None


def _sniff(args: argparse.Namespace) -> int:
    import can.cli

    from canbus.pdo_names import Dictionary, parse_assignment
    from canbus.recorder import enlarge_receive_buffer, recording_format
    from canbus.services import ServiceDecoder
    from canbus.sniffer import FrameFilter, Sniffer
    from skin.errors import BusError, ConfigError

    if args.record:
        recording_format(args.record)  # refused before the bus is opened
    for name in ("seconds", "refresh"):
        value = getattr(args, name)
        if value is not None and not value > 0:
            raise ConfigError(f"--{name}", f"must be positive, got {value}")
    assignments: dict[int, str] = {}
    for text in args.eds:
        assignments |= parse_assignment(text)
    decoder = ServiceDecoder(Dictionary(assignments))
    shown = FrameFilter(args.node, args.service)
    view = args.view or ("live" if sys.stdout.isatty() else "lines")
    stats = ViewStats()
    printer = LinePrinter(decoder, shown, sys.stdout, stats) if view == "lines" else None
    sniffer = Sniffer(decoder, bitrate=getattr(args, "bitrate", None) or 1_000_000,
                      data_bitrate=getattr(args, "data_bitrate", None),
                      on_frame=printer.on_frame if printer is not None else None)
    _default_channel(args)
    switch = sys.getswitchinterval()
    try:
        sys.setswitchinterval(min(switch, _SWITCH_S))
        with can.cli.create_bus_from_namespace(args) as bus:
            if args.rcvbuf:
                enlarge_receive_buffer(bus, args.rcvbuf)
            capture = _capture(bus, sniffer, shown, printer, stats, view, args)
    finally:
        sys.setswitchinterval(switch)
    _report(sniffer.snapshot(), capture, stats, view, args)
    if capture.error is not None:
        raise BusError(f"receiving stopped: {capture.error}") from capture.error
    return 0


def _capture(bus: can.BusABC, sniffer: Sniffer, shown: FrameFilter,
             printer: LinePrinter | None, stats: ViewStats, view: str,
             args: argparse.Namespace) -> Capture:
    """Receive until the end; the recording is saved (Ctrl-C included) or discarded."""
    import can

    from canbus.recorder import Recorder

    recorder = Recorder(args.record) if args.record else None
    try:
        listeners: list[can.Listener] = [sniffer] if recorder is None else [recorder, sniffer]
        notifier = can.Notifier(bus, listeners, timeout=_TICK_S)
        if printer is not None:
            printer.start()
        started, cpu = time.monotonic(), time.process_time()
        header = f"skin sniff {args.interface}:{args.channel}" + \
            (f" → {args.record}" if args.record else "")
        try:
            _watch(notifier, recorder, printer, sniffer, shown, stats, view, header, args,
                   started)
        except KeyboardInterrupt:
            pass  # Ctrl-C is how a sniffer is meant to end
        finally:
            try:
                notifier.stop()  # also stops the recorder: written, synced, renamed
            finally:
                if printer is not None:
                    printer.stop()
        seconds, cpu = time.monotonic() - started, time.process_time() - cpu
        if recorder is not None:
            recorder.stop()  # a no-op now, or the writer's error
    except BaseException:
        if recorder is not None:
            recorder.abort()
        raise
    return Capture(seconds, cpu, recorder.saved if recorder else None,
                   recorder.written if recorder else 0, notifier.exception)


def _report(snap: Snapshot, capture: Capture, stats: ViewStats, view: str,
            args: argparse.Namespace) -> None:
    from skin.atomic import atomic_write

    out = sys.stderr if view == "lines" else sys.stdout  # lines mode: stdout is the frames
    for line in summary_lines(snap, capture.seconds, stats):
        print(line, file=out)
    if capture.saved is not None:
        print(f"recorded {capture.recorded:,} frames to {capture.saved}", file=out)
    if args.json:
        record = snap.to_dict(capture.seconds) | {
            "cpu_share": capture.cpu_s / max(capture.seconds, 1e-9),
            "recording": None if capture.saved is None else
            {"path": str(capture.saved), "frames": capture.recorded},
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


def _default_channel(args: argparse.Namespace) -> None:
    from can.interfaces.udp_multicast import UdpMulticastBus

    if not hasattr(args, "channel"):
        args.channel = ("skin" if args.interface == "virtual"
                        else UdpMulticastBus.DEFAULT_GROUP_IPv4)


def _node_id(text: str) -> int:
    value = int(text, 0)
    if not 1 <= value <= 127:
        raise argparse.ArgumentTypeError(f"node-ID must be in 1..127, got {text}")
    return value


def add_subparser(subparsers: Any) -> None:
    import can.cli

    parser = subparsers.add_parser(
        "sniff", help="live, EDS-aware bus view; --record to .log/.asc/.blf/.pcap",
        description="Show every CANopen service on a bus, decoded with the EDS files, with "
                    "per COB-ID rates, bus load and anomaly counters; record every frame.")
    parser.add_argument("--eds", action="append", default=[], metavar="NODE=FILE",
                        help="decode node NODE (or FIRST-LAST) with FILE (a path or a shipped "
                             "EDS name); default: 1..64 skin-patch, 65..127 skin-forces")
    parser.add_argument("--node", action="append", type=_node_id, default=[], metavar="N",
                        help="show only node N (repeatable); statistics still see every frame")
    parser.add_argument("--service", action="append", choices=SERVICES, default=[],
                        help="show only this service (repeatable)")
    parser.add_argument("--record", metavar="FILE",
                        help="record every frame to FILE: .log (candump -L), .asc, .blf, .pcap")
    parser.add_argument("--seconds", type=float, default=None, metavar="S",
                        help="stop after S seconds (default: at Ctrl-C)")
    parser.add_argument("--view", choices=("live", "lines", "none"), default=None,
                        help="live table, one line per frame, or summary only "
                             "(default: live on a terminal, else lines)")
    parser.add_argument("--refresh", type=float, default=4.0, metavar="HZ",
                        help="live view redraws per second at most (default 4)")
    parser.add_argument("--rcvbuf", type=int, default=_RCVBUF, metavar="BYTES",
                        help="socket receive buffer to ask for on socket buses (udp_multicast, "
                             f"socketcan); 0 keeps the system's (default {_RCVBUF >> 20} MiB)")
    parser.add_argument("--json", metavar="FILE", help="write the summary as JSON")
    can.cli.add_bus_arguments(parser, filter_arg=True)
    parser.set_defaults(func=_sniff, interface="virtual")
