"""What a sniff shows at one instant: each COB-ID's row, the anomalies, the bus load
(:class:`Snapshot`, taken by :meth:`canbus.tools.sniffer.Sniffer.snapshot`)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import can

from canbus.tools.services import Decoded, Route, Service


@dataclass(frozen=True)
class CobRow:
    """One COB-ID at the moment of a snapshot."""

    cob_id: int
    extended: bool
    service: Service
    node: int | None
    label: str
    count: int
    first: float
    last: float
    dt_last_s: float
    dt_min_s: float
    dt_max_s: float
    known: bool
    last_msg: can.Message | None = field(compare=False, repr=False)
    last_text: str = ""

    @property
    def route(self) -> Route:
        return Route(self.service, self.node, self.label)

    @property
    def rate_hz(self) -> float:
        """Mean frame rate between the first and the last frame."""
        span = self.last - self.first
        return (self.count - 1) / span if self.count > 1 and span > 0 else 0.0

    def to_dict(self) -> dict[str, Any]:
        mean_dt = (self.last - self.first) / (self.count - 1) if self.count > 1 else None
        return {"cob_id": self.cob_id, "extended": self.extended, "service": str(self.service),
                "node": self.node, "label": self.label, "frames": self.count,
                "rate_hz": self.rate_hz, "dt_mean_s": mean_dt,
                "dt_min_s": self.dt_min_s if self.count > 1 else None,
                "dt_max_s": self.dt_max_s if self.count > 1 else None, "known": self.known}


@dataclass(frozen=True)
class Anomalies:
    missed_sync: int = 0
    incomplete_samples: int = 0
    complete_samples: int = 0
    heartbeat_gaps: int = 0
    unknown_frames: int = 0
    unknown_cob_ids: tuple[int, ...] = ()
    error_frames: int = 0
    unattributed_frames: int = 0
    """PDOs no node is known to send (``canbus.tools.attribution``): shown as bytes."""
    unattributed_cob_ids: tuple[int, ...] = ()


@dataclass(frozen=True)
class Snapshot:
    """Everything a view shows, copied at one instant."""

    taken_at: float
    frames: int
    first: float | None
    last: float | None
    bits_best: float
    bits_worst: float
    bitrate: int
    by_service: dict[str, int]
    rows: tuple[CobRow, ...]
    anomalies: Anomalies
    events: tuple[Decoded, ...]
    states: dict[int, str]

    def load_pct(self, seconds: float) -> tuple[float, float]:
        """Bus load over ``seconds``: (no stuffing, worst case) in %."""
        if seconds <= 0:
            return 0.0, 0.0
        scale = 100.0 / (self.bitrate * seconds)
        return self.bits_best * scale, self.bits_worst * scale

    def to_dict(self, seconds: float) -> dict[str, Any]:
        best, worst = self.load_pct(seconds)
        return {"seconds": seconds, "frames": self.frames, "bitrate": self.bitrate,
                "bus_load_pct": {"no_stuffing": best, "worst_case": worst},
                "by_service": self.by_service, "anomalies": asdict(self.anomalies),
                "nmt_states": {str(k): v for k, v in sorted(self.states.items())},
                "cob_ids": [row.to_dict() for row in self.rows]}
