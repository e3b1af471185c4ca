"""Statistics of a timed wire and its nodes: frozen snapshots and the sliding window behind them.

Times are on the wire's clock (``time.time()`` in real time; the simulated clock otherwise).
Busy time counts every bit a frame or an error frame holds the wire, intermission included,
the same bits ``skin plan`` counts, so ``load_pct`` is comparable with the plan's range.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import can


@dataclass(frozen=True)
class NodeStats:
    """One bus instance (a node on the wire)."""

    name: str
    fd: bool
    state: can.BusState
    """ACTIVE, PASSIVE (error passive: TEC or REC above 127) or ERROR (bus off)."""
    tec: int
    """Transmit error counter (ISO 11898-1: +8 per error, -1 per frame sent)."""
    rec: int
    """Receive error counter (+1 per error seen receiving, -1 per frame received)."""
    sent: int
    """Frames this node transmitted successfully."""
    received: int
    """Frames put in this node's receive queue."""
    lost_overflow: int
    """Frames this node received while its receive queue was full (dropped here only)."""
    errors: int
    """Error frames on frames this node transmitted."""
    bus_off_count: int
    pending: int
    """Frames in this node's transmit queue (the one on the wire included)."""


@dataclass(frozen=True)
class WireStats:
    """One channel's wire, since it started and over the last ``window_s``."""

    channel: str
    bitrate: int
    data_bitrate: int | None
    realtime: bool
    started: float
    """Wire clock (``time.time()`` scale) when the channel's first bus opened."""
    elapsed_s: float
    """Wire time from ``started`` to this snapshot (exact: kept apart from the large
    ``started``, whose float resolves only a quarter of a microsecond)."""
    frames: int
    """Frames delivered (data and remote frames that were acknowledged)."""
    nominal_bits: int
    """Bits of the delivered frames at the nominal rate (intermission included)."""
    data_bits: int
    """Bits of the delivered frames at the data rate (CAN FD with bit rate switch)."""
    error_frames: int
    retransmissions: int
    """Attempts of frames that had failed before (bit error, no acknowledgement)."""
    busy_s: float
    """Time the wire was held by frames and error frames, up to this snapshot."""
    window_s: float
    window_frames: int
    window_busy_s: float
    nodes: tuple[NodeStats, ...]

    @property
    def now(self) -> float:
        """Wire clock of this snapshot."""
        return self.started + self.elapsed_s

    @property
    def bits(self) -> int:
        return self.nominal_bits + self.data_bits

    @property
    def load_pct(self) -> float:
        """Busy share of the wire since it started."""
        return 100.0 * self.busy_s / self.elapsed_s if self.elapsed_s > 0 else 0.0

    @property
    def window_load_pct(self) -> float:
        """Busy share of the wire over the last ``window_s`` (or since it started, if less)."""
        span = min(self.window_s, self.elapsed_s)
        return 100.0 * self.window_busy_s / span if span > 0 else 0.0

    def load_since(self, earlier: WireStats) -> float:
        """Busy share in % between an earlier snapshot of the same wire and this one."""
        span = self.elapsed_s - earlier.elapsed_s
        return 100.0 * (self.busy_s - earlier.busy_s) / span if span > 0 else 0.0


class LoadWindow:
    """The wire's occupations over the last ``span_s`` seconds, for windowed load."""

    def __init__(self, span_s: float) -> None:
        self.span_s = span_s
        self._spans: deque[tuple[float, float, float | None]] = deque()

    def add(self, start: float, end: float, delivered: float | None) -> None:
        """An occupation of the wire; ``delivered``: when its frame arrived (None: error)."""
        spans = self._spans
        spans.append((start, end, delivered))
        horizon = end - self.span_s
        while spans[0][1] < horizon:
            spans.popleft()

    def measure(self, now: float, window_s: float) -> tuple[float, int]:
        """Busy seconds and delivered frames in ``[now - window_s, now]``."""
        low = now - min(window_s, self.span_s)
        busy, frames = 0.0, 0
        # From the newest back (one wire: the spans are in order), so that a short window
        # costs what it holds: this runs under the wire's lock.
        for start, end, delivered in reversed(self._spans):
            if end <= low:
                break
            if start >= now:
                continue
            busy += min(end, now) - max(start, low)
            frames += delivered is not None and low < delivered <= now
        return busy, frames
