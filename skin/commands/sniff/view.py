"""The views of ``skin sniff``: one line per frame, the live table, the summary.

They read snapshots of the sniffer's counters and never hold up the receive path:
:class:`LinePrinter` prints through a bounded queue and counts the lines it drops.
"""

from __future__ import annotations

import os
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, TextIO

if TYPE_CHECKING:
    import can
    from rich.console import RenderableType

    from canbus.tools.services import Decoded, Route, ServiceDecoder
    from canbus.tools.snapshot import Snapshot
    from canbus.tools.sniffer import FrameFilter

_LINE_QUEUE = 100_000
_LINES_POLL_S = 0.02


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
        from canbus.tools.services import Service

        texts = [d.text if d is not None else None for _, _, d in batch]
        labels = [d.label if d is not None else w.label for _, w, d in batch]
        groups: dict[tuple[int, int | None], list[int]] = {}
        for k, (msg, where, decoded) in enumerate(batch):
            if decoded is None and where.service is Service.PDO:
                groups.setdefault((msg.arbitration_id, where.node), []).append(k)
        for (cob_id, node), ks in groups.items():  # the node the frame was attributed to
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
                     f"({len(a.unknown_cob_ids)} ids)  unattributed {a.unattributed_frames} "
                     f"({len(a.unattributed_cob_ids)} ids)  error frames {a.error_frames}",
                     style="yellow" if any((a.missed_sync, a.incomplete_samples,
                                            a.heartbeat_gaps, a.unknown_frames,
                                            a.unattributed_frames, a.error_frames))
                     else "green")
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
        *unattributed_lines(a.unattributed_frames, a.unattributed_cob_ids),
        f"view: {stats.redraws} redraws ({stats.redraws_skipped} skipped), "
        f"{stats.lines:,} lines ({stats.lines_dropped:,} dropped)",
    ]


def unattributed_lines(frames: int, cob_ids: tuple[int, ...]) -> list[str]:
    """What to say of PDOs no node is known to send (empty when there are none)."""
    if not frames:
        return []
    from canbus.tools.attribution import cob_ranges

    return [f"unattributed PDOs: {frames:,} frames on {cob_ranges(cob_ids)}: no node is "
            "known to send them, so they are shown as bytes; give the host's --config "
            "HOST.toml (or --ask-by-sdo on a live bus) to name them"]
