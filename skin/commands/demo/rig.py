"""What ``skin demo`` measures: the simulation it serves, the bus clock, what the host
published, and the wire time of every cycle.

Each bus of the demo has a patch server (the simulated patches) on a canopen Network of
its own, and a :class:`BusClock` on that network's notifier, which sees every frame the
host sends (SYNC, force PDOs): so it knows when each SYNC went out and when each sample's
last force PDO reached the bus. On the timed bus the clock also keeps the frames the host
receives (the patches' own, handed to it by a listener on the host's notifier that only
appends them), so that after the run it knows how long every frame of a cycle held the
wire; nothing is computed on the data path.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    import can

    from canbus.master.dataplane import ForceFrame

SYNC_COB_ID = 0x080


class Replay:
    """A precomputed simulation served one step per read, filing each cycle's truth.

    ``on_sync`` must run before the patch server's own SYNC handler (subscribe it first):
    it turns the SYNC counter into the host's cycle number, and ``read`` files the true
    forces of the step it serves under that cycle in ``truth`` / ``known`` for the columns
    (patches) it serves.
    """

    def __init__(self, resistance_ohm: NDArray[np.float64], force_N: NDArray[np.float64],
                 node_ids: tuple[int, ...], columns: list[int], truth: NDArray[np.float64],
                 known: NDArray[np.bool_]) -> None:
        self.resistance_ohm, self.force_N = resistance_ohm, force_N
        self.node_ids = node_ids
        self.columns = columns
        self.pillars = int(resistance_ohm.shape[-1])
        self.truth, self.known = truth, known  # (cycles, patches, 9, 3), (cycles, patches)
        self.cycle = 0
        self.position = 0

    def on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if data:  # counter = cycle % 240 + 1: the next cycle with that counter
            self.cycle += (data[0] - 2 - self.cycle) % 240 + 1
        else:
            self.cycle += 1

    def read(self) -> NDArray[np.float64]:
        k = self.position % len(self.resistance_ohm)
        self.position += 1
        if self.cycle < len(self.truth):
            self.truth[self.cycle, self.columns] = self.force_N[k][self.columns]
            self.known[self.cycle, self.columns] = True
        sample: NDArray[np.float64] = self.resistance_ohm[k][self.columns]
        return sample


class BusClock:
    """Bus timestamps of every SYNC and of the last force PDO of every sample, and the
    wire time of each cycle's frames (timed bus: ``bitrate`` set)."""

    def __init__(self, last_force_cob: dict[int, int], bitrate: int | None,
                 data_bitrate: int | None) -> None:
        self.last_force_cob = last_force_cob  # COB-ID of a force node's last PDO -> its patch
        self.bitrate, self.data_bitrate = bitrate, data_bitrate
        self.syncs: list[float] = []
        self.ends: dict[int, list[float]] = {p: [] for p in last_force_cob.values()}
        self.force_frames = 0
        self.force_cobs: set[int] = set()
        self.seen: list[can.Message] = []  # every frame of the wire, both sides (timed bus)

    @classmethod
    def for_patches(cls, patches: Sequence[int], *, fd: bool, bitrate: int | None,
                    data_bitrate: int | None) -> BusClock:
        """The clock of a bus whose patches' force nodes (node-ID + 64) publish on their
        default TPDO COB-IDs: one force PDO a sample in CAN FD, eight in classic CAN (the
        seven of the forces and the contact's, which is sent last)."""
        from canbus.master.cobids import force_tpdo_cob_ids
        from canbus.master.hostconfig import FORCE_NODE_OFFSET

        pdos = {n: force_tpdo_cob_ids(n + FORCE_NODE_OFFSET)[:1 if fd else 8]
                for n in patches}
        clock = cls({cob_ids[-1]: n for n, cob_ids in pdos.items()}, bitrate, data_bitrate)
        clock.force_cobs = {c for cob_ids in pdos.values() for c in cob_ids}
        return clock

    def __call__(self, msg: can.Message) -> None:
        cob_id = msg.arbitration_id
        if self.bitrate is not None:
            self.seen.append(msg)
        if cob_id == SYNC_COB_ID:
            self.syncs.append(msg.timestamp)
        elif cob_id in self.force_cobs:
            self.force_frames += 1
            patch = self.last_force_cob.get(cob_id)
            if patch is not None:
                self.ends[patch].append(msg.timestamp)

    def host_side(self, msg: can.Message) -> None:
        """A frame the host received (the patches'): kept for the wire time."""
        self.seen.append(msg)

    def wire_ms(self) -> NDArray[np.float64]:
        """Per whole cycle (from one SYNC to the next), ms the cycle's frames held the
        wire: each frame's exact bits at the bus's rates (``canbus.framebits``)."""
        if self.bitrate is None or len(self.syncs) < 2:
            return np.empty(0)
        frames = [m for m in self.seen if not m.is_error_frame]
        stamps = np.array([m.timestamp for m in frames])
        durations = np.array([_duration_s(m, self.bitrate, self.data_bitrate) for m in frames])
        order = np.argsort(stamps, kind="stable")
        stamps, durations = stamps[order], durations[order]
        # a frame is stamped at its end: it belongs to the cycle its start falls in
        cycle = np.searchsorted(np.asarray(self.syncs), stamps - durations, side="right")
        per_cycle = np.bincount(cycle, weights=durations, minlength=len(self.syncs) + 1)
        out: NDArray[np.float64] = 1000.0 * per_cycle[1:len(self.syncs)].astype(np.float64)
        return out


def _duration_s(msg: can.Message, bitrate: int, data_bitrate: int | None) -> float:
    from canbus.framebits import frame_bits

    bits = frame_bits(msg.arbitration_id, bytes(msg.data), extended=msg.is_extended_id,
                      remote=msg.is_remote_frame, dlc=msg.dlc, fd=msg.is_fd,
                      brs=msg.bitrate_switch, esi=msg.error_state_indicator)
    return bits.duration_s(bitrate, data_bitrate)


class Record:
    """What the host published, per cycle and patch, in arrays allocated up front.

    The callback copies a frame into place and keeps the latest per patch for the live
    view: the run allocates no long-lived objects for the garbage collector to walk.
    """

    def __init__(self, cycles: int, node_ids: tuple[int, ...]) -> None:
        self.column = {n: j for j, n in enumerate(node_ids)}
        shape = (cycles, len(node_ids))
        self.force = np.zeros((*shape, 9, 3))
        self.valid = np.zeros((*shape, 9), dtype=bool)
        self.complete = np.zeros(shape, dtype=bool)
        self.published = np.zeros(shape, dtype=bool)
        self.latest: dict[int, ForceFrame] = {}

    def __call__(self, frame: ForceFrame) -> None:
        self.latest[frame.patch] = frame
        c, j = frame.cycle, self.column[frame.patch]
        if c < len(self.force):
            self.force[c, j] = frame.force_N
            self.valid[c, j] = frame.valid
            self.complete[c, j] = frame.complete
            self.published[c, j] = frame.published

    def sample_latencies_ms(self, clock: BusClock, patches: list[int]) -> NDArray[np.float64]:
        """SYNC -> last force PDO of every published sample of ``patches`` (one bus), in ms."""
        values = [v for by_cycle in self._latencies(clock, patches).values()
                  for v in by_cycle.values()]
        return np.array(values, dtype=np.float64)

    def cycle_latencies_ms(self, clock: BusClock, patches: list[int]) -> NDArray[np.float64]:
        """SYNC -> the last force PDO of the cycle (every patch of the bus published), ms."""
        per_patch = list(self._latencies(clock, patches).values())
        if not per_patch:
            return np.empty(0)
        cycles = set.intersection(*(set(d) for d in per_patch))
        return np.array([max(d[c] for d in per_patch) for c in sorted(cycles)],
                        dtype=np.float64)

    def _latencies(self, clock: BusClock, patches: list[int]) -> dict[int, dict[int, float]]:
        """Per patch, per cycle: ms from the cycle's SYNC to the sample's last force PDO;
        the i-th last PDO of a force node ends the i-th published sample of its patch."""
        syncs = np.asarray(clock.syncs)
        out: dict[int, dict[int, float]] = {}
        for patch in patches:
            j = self.column[patch]
            cycles = np.flatnonzero(self.published[:, j])
            ends = np.asarray(clock.ends[patch][: len(cycles)])
            cycles = cycles[: len(ends)]
            ok = (cycles >= 1) & (cycles <= len(syncs))
            latency = 1000.0 * (ends[ok] - syncs[cycles[ok] - 1])
            out[patch] = dict(zip(cycles[ok].tolist(), latency.tolist(), strict=True))
        return out

    def rmse_N(self, truth: NDArray[np.float64], known: NDArray[np.bool_]) -> float:
        """Over the valid taxels of complete samples whose truth is known."""
        chosen = self.complete & known
        error = (self.force[chosen] - truth[chosen])[self.valid[chosen]]
        return float(np.sqrt(np.mean(error ** 2))) if error.size else math.nan


def percentiles(values: NDArray[np.float64], qs: list[float]) -> list[float]:
    return np.percentile(values, qs).tolist() if values.size else [math.nan] * len(qs)
