"""Bus-load planner: bounds on a frame's bits, and the load N patches put on their buses.

Per-frame bounds and payloads: ``canbus.frametime`` (re-exported here).

The plan counts every frame that crosses a bus in operation: the patches' TPDOs, one SYNC
per cycle per bus (1-byte counter; its rate is the sample rate), the force PDOs the host
republishes when they share the bus, and heartbeats (patches every ``heartbeat_ms``, force
nodes every ``force_heartbeat_ms``). SYNC, heartbeats, NMT, SDO and EMCY stay classic frames
on a CAN FD bus. Set-up traffic (SDO, NMT) and EMCY are rare and not counted.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from canbus.frametime import (
    force_payloads,
    frame_time_s,
    patch_payloads,
)
from canbus.nodeload import Traffic, bus_figures, figures

Forces = Literal["same-bus", "other-bus", "none"]
FORCES: tuple[Forces, ...] = ("same-bus", "other-bus", "none")
SYNC_COB_ID = 0x080
HEARTBEAT_BASE = 0x700
FORCE_NODE_OFFSET = 64
"""A patch's force node is at node-ID patch + 64 (the host's default)."""
TPDO_BASES = (0x180, 0x280, 0x380, 0x480, 0x200, 0x300, 0x400, 0x500)
"""COB-ID bases of TPDO 1..7 (1..4 predefined, 5..7 on the unused predefined RPDO 1..3 ids)."""
CYCLIC = ("sync", "patch_pdo", "force_pdo")
"""Frame kinds sent once per SYNC cycle; heartbeats run on their own period."""


@dataclass(frozen=True)
class PlannedFrame:
    """One periodic frame on a bus, as the plan counts it."""

    kind: str
    """``patch_pdo``, ``force_pdo``, ``sync`` or ``heartbeat``."""
    cob_id: int
    data_bytes: int
    """Payload as the sender gives it (a CAN FD controller pads it to a DLC length)."""
    fd: bool
    """CAN FD with bit rate switch; else a classic frame."""
    per_s: float
    best_s: float
    """Wire time without stuffing."""
    worst_s: float
    """Wire time with worst-case stuffing."""


@dataclass(frozen=True)
class BusPlan:
    """The frames on one bus and the load they make."""

    name: str
    patches: tuple[int, ...]
    """Node-IDs of the patches whose TPDOs cross this bus."""
    force_nodes: tuple[int, ...]
    """Node-IDs of the force nodes whose PDOs cross this bus."""
    frames: tuple[PlannedFrame, ...]
    """Every frame, with ``plan(exact=True)``; empty otherwise (the figures come from one
    node's share, ``canbus.nodeload``)."""
    frames_per_s: dict[str, float]
    """By kind."""
    load_best_pct: float
    load_worst_pct: float
    cycle_ms_best: float
    """Wire time of one cycle's frames (SYNC, patch and force PDOs), no stuffing."""
    cycle_ms_worst: float
    max_rate_hz: float
    """The largest sample rate with the worst-case load at the target."""
    max_patch_samples_per_s: float
    """Samples per second of all patches on this bus together at ``max_rate_hz``."""
    latency_ms_worst: float | None
    """From a SYNC due to the last frame of its cycle on the wire, worst case
    (``canbus.nodeload.figures``); None when the bus does not fit."""
    fits: bool
    """The worst-case load is at most 100 %."""
    over_target: bool


@dataclass(frozen=True)
class Plan:
    """The load of ``patches`` patches at ``rate_hz`` on ``buses`` buses (and a force bus)."""

    patches: int
    rate_hz: float
    mode: str
    bitrate: int
    data_bitrate: int | None
    forces: Forces
    heartbeat_ms: int
    force_heartbeat_ms: int
    frames_per_sample: int
    """Frames a patch sends per sample."""
    force_frames_per_sample: int
    """Frames a force node sends per sample (0 with ``forces="none"``)."""
    frames_per_s: float
    """On all buses together."""
    buses: tuple[BusPlan, ...]
    worst_bus: str
    """The bus with the highest worst-case load; the top-level load is its load."""
    load_best_pct: float
    load_worst_pct: float
    cycle_ms_best: float
    cycle_ms_worst: float
    target_pct: float
    max_rate_hz: float
    """The largest sample rate every bus carries under the target."""
    max_patch_samples_per_s: float
    """The smallest, over the buses with patches, of their patch-samples/s under the target."""
    fits: bool
    over_target: bool


def spread(node_ids: Sequence[int], buses: int) -> list[tuple[int, ...]]:
    """``node_ids`` in order over ``buses`` buses, as evenly as possible (the first get more)."""
    size, extra = divmod(len(node_ids), buses)
    out, at = [], 0
    for k in range(buses):
        n = size + (k < extra)
        out.append(tuple(node_ids[at:at + n]))
        at += n
    return out


def _frame(kind: str, cob_id: int, data_bytes: int, per_s: float, bitrate: int,
           data_bitrate: int | None, fd: bool) -> PlannedFrame:
    best = frame_time_s(data_bytes, bitrate, data_bitrate, fd=fd, worst_case_stuffing=False)
    worst = frame_time_s(data_bytes, bitrate, data_bitrate, fd=fd, worst_case_stuffing=True)
    return PlannedFrame(kind, cob_id, data_bytes, fd, per_s, best, worst)


def _node_frames(kind: str, node: int, payloads: list[int], rate_hz: float,
                 heartbeat_ms: int, bitrate: int, data_bitrate: int | None) -> list[PlannedFrame]:
    fd = data_bitrate is not None
    out = [_frame(kind, base + node, size, rate_hz, bitrate, data_bitrate, fd)
           for base, size in zip(TPDO_BASES, payloads, strict=False)]
    if heartbeat_ms > 0:
        out.append(_frame("heartbeat", HEARTBEAT_BASE + node, 1, 1000.0 / heartbeat_ms,
                          bitrate, None, False))
    return out


def _bus(name: str, patches: tuple[int, ...], force_nodes: tuple[int, ...], sync: bool, *,
         mode: str, rate_hz: float, bitrate: int, data_bitrate: int | None, target_pct: float,
         heartbeat_ms: int, force_heartbeat_ms: int, contact: bool) -> BusPlan:
    """One bus, every frame listed and summed (``plan(exact=True)``)."""

    fd = data_bitrate is not None
    frames: list[PlannedFrame] = []
    if sync:
        frames.append(_frame("sync", SYNC_COB_ID, 1, rate_hz, bitrate, None, False))
    for node in patches:
        frames += _node_frames("patch_pdo", node, patch_payloads(mode, fd=fd), rate_hz,
                               heartbeat_ms, bitrate, data_bitrate)
    for node in force_nodes:
        frames += _node_frames("force_pdo", node, force_payloads(fd=fd, contact=contact), rate_hz,
                               force_heartbeat_ms, bitrate, data_bitrate)
    per_s: dict[str, float] = {}
    for f in frames:
        per_s[f.kind] = per_s.get(f.kind, 0.0) + f.per_s
    best = sum(f.per_s * f.best_s for f in frames)
    worst = sum(f.per_s * f.worst_s for f in frames)
    cyclic = [f for f in frames if f.kind in CYCLIC]
    cycle_best = sum(f.best_s for f in cyclic)
    cycle_worst = sum(f.worst_s for f in cyclic)
    fixed = worst - rate_hz * cycle_worst  # heartbeats: their rate does not follow the SYNC
    shown = figures(per_s, best, worst, cycle_best, cycle_worst, fixed,
                    max(f.worst_s for f in frames), len(patches or force_nodes), rate_hz,
                    target_pct)
    return BusPlan(name=name, patches=patches, force_nodes=force_nodes, frames=tuple(frames),
                   **vars(shown))


def plan(patches: int, rate_hz: float, mode: str, bitrate: int, *,
         data_bitrate: int | None = None, target_pct: float = 70.0,
         forces: Forces = "same-bus", buses: int = 1, heartbeat_ms: int = 100,
         force_heartbeat_ms: int = 1000, contact: bool = True, exact: bool = False) -> Plan:
    """The load of every bus: patches 1..N spread over ``buses`` buses in node order.

    ``data_bitrate`` set means CAN FD: one PDO per sample with bit rate switch. ``forces``:
    ``same-bus`` puts each patch's force PDOs (force node patch + 64) on the patch's bus,
    ``other-bus`` all of them on one more bus (named ``forces``; no SYNC there: force PDOs
    are event-driven), ``none`` leaves them out. A heartbeat period of 0 disables it.
    ``contact``: the force nodes publish the contact summary (TPDO 8; the host's default).
    ``exact``: list every frame of every bus and sum them (``BusPlan.frames``); else each
    bus's figures come from one node's share times the nodes (``canbus.nodeload``), in time
    linear in the buses.
    """

    if mode not in ("z", "xyz"):
        raise ValueError(f"mode is z or xyz, got {mode!r}")
    if forces not in FORCES:
        raise ValueError(f"forces is one of {', '.join(FORCES)}, got {forces!r}")
    if patches < 1 or buses < 1:
        raise ValueError("patches and buses must be at least 1")
    if buses > patches:
        raise ValueError(f"{buses} buses for {patches} patches: a bus would carry none")
    fd = data_bitrate is not None
    traffic = Traffic.of(rate_hz, mode, bitrate, data_bitrate, heartbeat_ms=heartbeat_ms,
                         force_heartbeat_ms=force_heartbeat_ms, contact=contact)

    def bus(name: str, group: Sequence[int], force_nodes: Sequence[int], sync: bool) -> BusPlan:
        nodes = tuple(n + FORCE_NODE_OFFSET for n in force_nodes)
        if not exact:
            shown = bus_figures(traffic, len(group), len(nodes), sync, target_pct)
            return BusPlan(name=name, patches=tuple(group), force_nodes=nodes, frames=(),
                           **vars(shown))
        return _bus(name, tuple(group), nodes, sync, mode=mode, rate_hz=rate_hz,
                    bitrate=bitrate, data_bitrate=data_bitrate, target_pct=target_pct,
                    heartbeat_ms=heartbeat_ms, force_heartbeat_ms=force_heartbeat_ms,
                    contact=contact)

    groups = spread(range(1, patches + 1), buses)
    plans = [bus(f"bus {k}", group, group if forces == "same-bus" else (), True)
             for k, group in enumerate(groups)]
    if forces == "other-bus":
        plans.append(bus("forces", (), range(1, patches + 1), False))
    worst = max(plans, key=lambda p: p.load_worst_pct)
    with_patches = [p for p in plans if p.patches]
    return Plan(
        patches=patches, rate_hz=rate_hz, mode=mode, bitrate=bitrate,
        data_bitrate=data_bitrate, forces=forces, heartbeat_ms=heartbeat_ms,
        force_heartbeat_ms=force_heartbeat_ms,
        frames_per_sample=len(patch_payloads(mode, fd=fd)),
        force_frames_per_sample=0 if forces == "none" else len(
            force_payloads(fd=fd, contact=contact)),
        frames_per_s=sum(sum(p.frames_per_s.values()) for p in plans),
        buses=tuple(plans), worst_bus=worst.name,
        load_best_pct=worst.load_best_pct, load_worst_pct=worst.load_worst_pct,
        cycle_ms_best=worst.cycle_ms_best, cycle_ms_worst=worst.cycle_ms_worst,
        target_pct=target_pct, max_rate_hz=min(p.max_rate_hz for p in plans),
        max_patch_samples_per_s=min(p.max_patch_samples_per_s for p in with_patches),
        fits=all(p.fits for p in plans), over_target=any(p.over_target for p in plans))
