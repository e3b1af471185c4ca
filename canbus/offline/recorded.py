"""The resistances a recording carries, one sample per patch per SYNC, judged as the host's
data plane judges a live bus.

:func:`read_patch_samples` first reads what the recording shows about each patch
(:mod:`canbus.tools.recording_facts`: the TPDO mapping its SDO writes left, its heartbeat,
LSB and R0, the SYNC period), then plays the recording through the listen-only host on
the recording's own clock (:func:`canbus.offline.decode.decode_recording`), and keeps the
raw samples its publisher hands on (:class:`~canbus.master.rawsample.RawSample`: the
resistances the data plane assembled, before any decoder). So a sample is complete,
incomplete or missing by exactly the data plane's answer rules (one unbroken run of one
answer per SYNC, in its window), its taxels are masked by the EMCYs on the bus, and a
patch that stopped beating is lost, as on the live bus; nothing of those rules is
repeated here. The host decodes with the analytic decoder, the default of a config
without a model; its forces are not read.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from canbus.master.busconfig import BusConfig
from canbus.master.hostconfig import FORCE_NODE_OFFSET, HostConfig, PatchConfig
from canbus.master.patch_setup import tpdo_layouts
from canbus.master.rawsample import RawSample
from canbus.offline.decode import decode_recording
from canbus.pdo_codec import TpdoLayout
from canbus.tools.recording_facts import RecordingFacts, scan_recording
from decoder.reasons import Reason, classify_resistance, worst_reason
from skin.constants import DEFAULT_CONSTANTS, TAXELS_PER_PATCH
from skin.errors import ConfigError, RecordingError

MAPPINGS = ("z", "xyz", "fd-z", "fd-xyz")
"""What ``--mapping`` names: the host's mapping of a mode, classic or CAN FD."""
EDS_HEARTBEAT_MS = 1000
"""A patch's heartbeat period when no master set one (eds/skin-patch.eds, 0x1017)."""


@dataclass(frozen=True)
class PatchMapping:
    """How a patch's answers are laid out in the recording."""

    node_id: int
    mode: str  # "z" or "xyz"
    fd: bool
    source: str  # "sdo" (what the recording's SDO transfers left), "eds" or "option"

    @property
    def name(self) -> str:
        return f"fd-{self.mode}" if self.fd else self.mode

    @property
    def pillars(self) -> int:
        return 1 if self.mode == "z" else 3


@dataclass(frozen=True)
class PatchSamples:
    """One patch's samples, one per SYNC of the recording, in cycle order."""

    node_id: int
    mapping: PatchMapping
    cycle: NDArray[np.int64]  # (n,) the listen-only host's cycle (1, 2, ... per SYNC heard)
    sync_counter: NDArray[np.int64]  # (n,) 0 without a counter
    time_s: NDArray[np.float64]  # (n,) the SYNC's timestamp in the recording
    complete: NDArray[np.bool_]  # (n,) every TPDO of one answer, in order, in the window
    resistance_ohm: NDArray[np.float64]  # (n, 9, P) as the patch sent them; NaN if invalid
    reason: NDArray[np.uint8]  # (n, 9) OK, or MISSING, FAULTY (EMCY), OPEN, SHORT, ...
    lsb_ohm: float
    r0_reported_ohm: NDArray[np.float64] | None  # (9, 3) if the recording showed 0x2002

    @property
    def usable(self) -> NDArray[np.bool_]:
        """Complete samples with every taxel read."""
        ok: NDArray[np.bool_] = self.complete & np.all(self.reason == Reason.OK, axis=1)
        return ok

    def counts(self) -> dict[str, Any]:
        """Samples by what became of them, and the faulty taxels of complete samples."""
        missing = np.all(self.reason == Reason.MISSING, axis=1)
        faulty = self.complete & ~self.usable
        taxels: dict[str, int] = {}
        codes, numbers = np.unique(self.reason[self.complete], return_counts=True)
        for code, number in zip(codes.tolist(), numbers.tolist(), strict=True):
            if code != Reason.OK:
                taxels[Reason(code).name] = int(number)
        return {"samples": int(self.cycle.size), "complete": int(self.complete.sum()),
                "usable": int(self.usable.sum()),
                "incomplete": int((~self.complete & ~missing).sum()),
                "unanswered": int((~self.complete & missing).sum()),
                "with_faulty_taxels": int(faulty.sum()), "faulty_taxels": taxels}


@dataclass(frozen=True)
class RecordedSamples:
    """Every patch's samples, and what the recording showed."""

    source: str
    patches: dict[int, PatchSamples]
    facts: RecordingFacts
    config: HostConfig  # the listen-only host's config the recording was read with


def resolve_mappings(facts: RecordingFacts, override: str | None = None
                     ) -> dict[int, PatchMapping]:
    """Each patch's mapping: ``override`` (one of :data:`MAPPINGS`) or what the recording
    shows, which must be one of the host's mappings. Raises RecordingError naming the frame
    (a patch remapped while it sends, or one that sends no PDO) or ConfigError."""
    if override is not None and override not in MAPPINGS:
        raise ConfigError("--mapping", f"must be one of {', '.join(MAPPINGS)}, got {override!r}")
    out: dict[int, PatchMapping] = {}
    for node, patch in facts.patches.items():
        if override is not None:
            mode = override.removeprefix("fd-")
            out[node] = PatchMapping(node, mode, override.startswith("fd-"), "option")
            continue
        if patch.first_pdo_frame is None:
            raise RecordingError(facts.source, None, f"patch {node} sends no PDO in the "
                                 "recording (is it the node-ID the reference names?)")
        if patch.remapped_frame is not None:
            raise RecordingError(facts.source, patch.remapped_frame, f"patch {node} sends PDOs "
                                 "under another mapping than its first ones: cut the "
                                 "recording where it was remapped")
        found = [(mode, fd) for mode in ("xyz", "z") for fd in (False, True)
                 if tpdo_layouts(node, mode, fd=fd) == patch.layouts]
        if not found:
            raise RecordingError(facts.source, patch.first_pdo_frame, f"patch {node}'s TPDO "
                                 f"mapping ({_describe(patch.layouts)}) is none of "
                                 f"{', '.join(MAPPINGS)}: give --mapping")
        mode, fd = found[0]
        out[node] = PatchMapping(node, mode, fd, "sdo" if patch.mapping_from_sdo else "eds")
    if len({m.fd for m in out.values()}) > 1:
        raise ConfigError("--mapping", "the patches of one recording answer in classic CAN "
                          "and in CAN FD: give --mapping")
    return out


def _describe(layouts: tuple[TpdoLayout, ...]) -> str:
    if not layouts:
        return "no valid TPDO"
    return "; ".join(f"TPDO{lay.number} 0x{lay.cob_id:03X}: "
                     + " ".join(f"{e.index:04X}:{e.subindex:02X}" for e in lay.entries)
                     for lay in layouts)


def listen_config(facts: RecordingFacts, mappings: dict[int, PatchMapping], *,
                  sync_window_ms: float | None = None, heartbeat_ms: int | None = None,
                  answer_order: str = "cob-id") -> HostConfig:
    """The listen-only host that reads the recording as its master ran it: the SYNC period
    the recording shows, a window of ``sync_window_ms`` (default 80 % of it, the host's
    default), the heartbeat period its master wrote to the patches (else the one they beat
    at; else the EDS default), the LSB the patches reported."""
    period_s = facts.sync_period_s
    if period_s is None or not period_s > 0:
        raise RecordingError(facts.source, None, f"{len(facts.sync_times)} SYNC frame(s): "
                             "a sample needs a SYNC before and after it")
    period_ms = 1000.0 * period_s
    window = 0.8 * period_ms if sync_window_ms is None else sync_window_ms
    if not 0 < window <= period_ms:
        raise ConfigError("--sync-window-ms", f"must be in (0, {period_ms:.3g}] (the "
                          f"recording's SYNC period), got {window:g}")
    ids = set(mappings)
    patches: list[PatchConfig] = []
    for node, mapping in sorted(mappings.items()):
        facts_of = facts.patches[node]
        constants = DEFAULT_CONSTANTS if facts_of.lsb_ohm is None else \
            dataclasses.replace(DEFAULT_CONSTANTS, resistance_lsb_ohm=facts_of.lsb_ohm)
        force = node + FORCE_NODE_OFFSET
        if force > 127 or force in ids:
            force = max(set(range(1, 128)) - ids - {p.force_node for p in patches})
        patches.append(PatchConfig(node_id=node, mode=mapping.mode, constants=constants,
                                   force_node=force, answer_order=answer_order))
    return HostConfig(
        patches=tuple(patches), sync_period_ms=period_ms, sync_window_ms=window,
        heartbeat_ms=heartbeat_ms or _heartbeat_ms(facts), listen_only=True, scan=False,
        buses=(BusConfig(fd=any(m.fd for m in mappings.values())),),
        source=f"(listen-only reading of {facts.source})").check()


def _heartbeat_ms(facts: RecordingFacts) -> int:
    """The longest period any patch beats at, as the recording shows it."""
    periods = []
    for patch in facts.patches.values():
        if patch.heartbeat_ms_written:
            periods.append(float(patch.heartbeat_ms_written))
        elif patch.heartbeat_ms_measured is not None:
            periods.append(patch.heartbeat_ms_measured)
        else:
            periods.append(float(EDS_HEARTBEAT_MS))
    return min(0xFFFF, math.ceil(max(periods)))


def read_patch_samples(path: str | os.PathLike[str], node_ids: tuple[int, ...], *,
                       mapping: str | None = None, sync_window_ms: float | None = None,
                       heartbeat_ms: int | None = None,
                       answer_order: str = "cob-id") -> RecordedSamples:
    """Every SYNC's sample of each of ``node_ids`` in the recording (module docstring)."""
    facts = scan_recording(path, node_ids)
    mappings = resolve_mappings(facts, mapping)
    config = listen_config(facts, mappings, sync_window_ms=sync_window_ms,
                           heartbeat_ms=heartbeat_ms, answer_order=answer_order)
    samples: list[RawSample] = []
    decode_recording(path, config, on_raw=samples.extend)
    patches = {}
    for node, mapped in mappings.items():
        mine = sorted((s for s in samples if s.patch == node), key=lambda s: s.cycle)
        n = len(mine)
        constants = config.patch(node).constants or DEFAULT_CONSTANTS
        readings = np.array([s.resistance_ohm for s in mine]).reshape(
            n, TAXELS_PER_PATCH, mapped.pillars)
        seen = np.array([s.reason for s in mine], dtype=np.uint8).reshape(n, TAXELS_PER_PATCH)
        # The reserved codes: open and saturated read +inf (OPEN), short 0 ohm (SHORT).
        reason = np.where(seen != Reason.OK, seen,
                          worst_reason(classify_resistance(readings, constants)))
        readings[reason != Reason.OK] = np.nan
        facts_of = facts.patches[node]
        r0 = None
        if len(facts_of.r0_ohm) == 3 * TAXELS_PER_PATCH:
            r0 = np.array([facts_of.r0_ohm[s] for s in range(1, 28)]).reshape(9, 3)
        patches[node] = PatchSamples(
            node_id=node, mapping=mapped,
            cycle=np.array([s.cycle for s in mine], dtype=np.int64),
            sync_counter=np.array([s.sync_counter for s in mine], dtype=np.int64),
            time_s=np.array([s.timestamp for s in mine], dtype=np.float64),
            complete=np.array([s.complete for s in mine], dtype=bool),
            resistance_ohm=readings, reason=reason.astype(np.uint8),
            lsb_ohm=constants.resistance_lsb_ohm, r0_reported_ohm=r0)
    return RecordedSamples(os.fspath(path), patches, facts, config)
