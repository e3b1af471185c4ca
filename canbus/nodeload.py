"""The planner's arithmetic: a bus's load from how many patches and force nodes it carries.

Every patch sends the same frames (the same payload sizes at the same rates; only the
COB-IDs differ, and a frame's bounds do not depend on its id), and so does every force node.
So a bus's load is its SYNC's plus the number of patches times one patch's plus the number of
force nodes times one force node's: :class:`NodeTraffic` is one node's share, counted once,
and :func:`bus_figures` adds them up in constant time, whatever the size of the skin.
``canbus.busload.plan(exact=True)`` lists every frame and sums them one by one instead; the
two agree to rounding (tests/canbus/test_plan_arithmetic.py).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from canbus.frametime import force_payloads, frame_time_s, patch_payloads


@dataclass(frozen=True)
class NodeTraffic:
    """What one node (a patch or a force node) puts on its bus."""

    pdo_frames: int
    """Frames per sample."""
    cycle_best_s: float
    """Wire time of one sample's frames, no stuffing."""
    cycle_worst_s: float
    heartbeats_per_s: float
    heartbeat_best_s: float
    heartbeat_worst_s: float
    longest_worst_s: float
    """The longest of its frames, worst-case stuffing."""


def node_traffic(payloads: list[int], heartbeat_ms: int, bitrate: int,
                 data_bitrate: int | None) -> NodeTraffic:
    """One node's share: its PDOs of one sample (``payloads``), and its heartbeat."""
    fd = data_bitrate is not None
    best = [frame_time_s(n, bitrate, data_bitrate, fd=fd, worst_case_stuffing=False)
            for n in payloads]
    worst = [frame_time_s(n, bitrate, data_bitrate, fd=fd, worst_case_stuffing=True)
             for n in payloads]
    beat_best, beat_worst = (frame_time_s(1, bitrate, None, fd=False, worst_case_stuffing=w)
                             for w in (False, True))
    beats = 1000.0 / heartbeat_ms if heartbeat_ms > 0 else 0.0
    return NodeTraffic(pdo_frames=len(payloads), cycle_best_s=sum(best),
                       cycle_worst_s=sum(worst), heartbeats_per_s=beats,
                       heartbeat_best_s=beat_best, heartbeat_worst_s=beat_worst,
                       longest_worst_s=max(worst + ([beat_worst] if beats else [])))


@dataclass(frozen=True)
class Traffic:
    """The shares of a patch, of its force node, and of a SYNC, for one plan's settings."""

    rate_hz: float
    patch: NodeTraffic
    force: NodeTraffic
    sync_best_s: float
    sync_worst_s: float

    @classmethod
    def of(cls, rate_hz: float, mode: str, bitrate: int, data_bitrate: int | None, *,
           heartbeat_ms: int, force_heartbeat_ms: int, contact: bool) -> Traffic:
        fd = data_bitrate is not None
        return cls(
            rate_hz=float(rate_hz),
            patch=node_traffic(patch_payloads(mode, fd=fd), heartbeat_ms, bitrate,
                               data_bitrate),
            force=node_traffic(force_payloads(fd=fd, contact=contact), force_heartbeat_ms,
                               bitrate, data_bitrate),
            sync_best_s=frame_time_s(1, bitrate, None, fd=False, worst_case_stuffing=False),
            sync_worst_s=frame_time_s(1, bitrate, None, fd=False, worst_case_stuffing=True))


@dataclass(frozen=True)
class BusFigures:
    """A bus's figures, as ``canbus.busload.BusPlan`` reports them (its fields' meaning)."""

    frames_per_s: dict[str, float]
    load_best_pct: float
    load_worst_pct: float
    cycle_ms_best: float
    cycle_ms_worst: float
    max_rate_hz: float
    max_patch_samples_per_s: float
    latency_ms_worst: float | None
    fits: bool
    over_target: bool


def _frames_per_s(t: Traffic, patches: int, force_nodes: int, sync: bool) -> dict[str, float]:
    """Frames/s by kind, the kinds in the order the frame-by-frame plan meets them."""
    per_s: dict[str, float] = {}
    if sync:
        per_s["sync"] = t.rate_hz
    for kind, count, node in (("patch_pdo", patches, t.patch),
                              ("force_pdo", force_nodes, t.force)):
        if count:
            per_s[kind] = count * node.pdo_frames * t.rate_hz
            if node.heartbeats_per_s:
                per_s["heartbeat"] = per_s.get("heartbeat", 0.0) + \
                    count * node.heartbeats_per_s
    return per_s


def bus_figures(t: Traffic, patches: int, force_nodes: int, sync: bool,
                target_pct: float) -> BusFigures:
    """The figures of a bus of ``patches`` patches and ``force_nodes`` force nodes (and a
    SYNC if ``sync``), in constant time."""
    nodes = ((patches, t.patch), (force_nodes, t.force))
    cycle_best = (t.sync_best_s if sync else 0.0) + sum(n * x.cycle_best_s for n, x in nodes)
    cycle_worst = (t.sync_worst_s if sync else 0.0) + sum(n * x.cycle_worst_s
                                                          for n, x in nodes)
    beats_best = sum(n * x.heartbeats_per_s * x.heartbeat_best_s for n, x in nodes)
    beats_worst = sum(n * x.heartbeats_per_s * x.heartbeat_worst_s for n, x in nodes)
    best = t.rate_hz * cycle_best + beats_best
    worst = t.rate_hz * cycle_worst + beats_worst
    return figures(_frames_per_s(t, patches, force_nodes, sync), best, worst, cycle_best,
                   cycle_worst, beats_worst, _longest(t, patches, force_nodes, sync),
                   patches or force_nodes, t.rate_hz, target_pct)


def _longest(t: Traffic, patches: int, force_nodes: int, sync: bool) -> float:
    return max([t.sync_worst_s] * sync + [t.patch.longest_worst_s] * bool(patches)
               + [t.force.longest_worst_s] * bool(force_nodes))


def figures(frames_per_s: dict[str, float], best: float, worst: float, cycle_best: float,
            cycle_worst: float, fixed: float, longest: float, samples: int, rate_hz: float,
            target_pct: float) -> BusFigures:
    """A bus's figures from its loads (fractions of the wire), its cycle's wire time, its
    load that does not follow the SYNC (``fixed``: heartbeats) and its longest frame (s).

    The worst-case latency is from a SYNC due to the last frame of its cycle on the wire:
    the longest frame already on the wire (a frame is not interrupted), then every frame of
    the cycle back to back (the force PDOs of the sample before may win arbitration over a
    patch's); heartbeats, of the lowest priority, only as that frame. None when the bus does
    not fit: its queues grow without bound.
    """
    room = target_pct / 100.0 - fixed
    max_rate = max(room, 0.0) / cycle_worst if cycle_worst else float("inf")
    fits = worst <= 1.0
    return BusFigures(
        frames_per_s=frames_per_s, load_best_pct=100.0 * best, load_worst_pct=100.0 * worst,
        cycle_ms_best=1e3 * cycle_best, cycle_ms_worst=1e3 * cycle_worst,
        max_rate_hz=max_rate, max_patch_samples_per_s=max_rate * samples,
        latency_ms_worst=1e3 * (longest + cycle_worst) if fits else None,
        fits=fits, over_target=100.0 * worst > target_pct)


def most_under(load_pct: Callable[[int], float], target_pct: float, limit: int) -> int:
    """The most nodes (0..``limit``) a bus carries with ``load_pct(n)``, its worst-case load,
    at most the target (the load grows with n: a bisection)."""
    low, high = 0, limit
    while low < high:
        mid = (low + high + 1) // 2
        if load_pct(mid) <= target_pct:
            low = mid
        else:
            high = mid - 1
    return low
