"""The data plane: patch TPDOs in, forces out, one SYNC cycle at a time.

One ``can.Listener`` takes every frame on the bus. Its hot path looks the COB-ID up in a
table (COB-ID -> channel slot, PDO position), checks the frame against the open SYNC
cycle and copies the payload into that slot's preallocated buffer; nothing else happens
per frame. When every PDO of a patch has arrived exactly once, the patch's payload is
queued; the publisher decodes what is queued in numpy batches (one ``PdoCodec.unpack``
per PDO layout, one ``decode`` per decoder object) and sends the force nodes' TPDOs
with ``bus.send``.

Cycle rules: :mod:`canbus.answers`, the one assembly of a patch's answers that the sniffer,
the view and ``skin decode`` judge them by too. A patch answers SYNC k with its
synchronous TPDOs, in a fixed order (:attr:`PatchChannel.answer_order`); a frame counts for
cycle k only if it lies in the SYNC window (``sync_window_s`` after t_k, the time the host
sent SYNC k or heard it; 0: until the next SYNC) and extends the answer that began there,
in order; a PDO taken already, again, ends the answer, but the frame just taken again with
the same bytes (a CAN retransmission) changes nothing. So a sample is complete only when
every TPDO of one answer arrived once, in order, in the window, and the data of two
answers is never mixed.

When a cycle closes: where the bus passed the next SYNC, not where the host sent it
(:mod:`canbus.master.syncpassage`; :meth:`DataPlane.on_sync_sent` announces a SYNC the host
sends, :meth:`DataPlane.on_sync` opens the cycle of one heard on the bus, at once).

A complete patch is published at once; every other patch is published when the next
SYNC (or :meth:`flush`) closes the cycle, incomplete: taxels carried by a missing PDO
are invalid with ``Reason.MISSING`` (every taxel, when nothing usable arrived). So each
patch gets exactly one force sample per SYNC, and a consumer can count cycles.

Publishing: by default a thread of the data plane decodes and publishes, so that
patches completing while it works are batched into its next round (the notifier thread
only copies bytes). ``background=False`` leaves that to the caller
(:meth:`publish_pending`), as the benchmark does to run everything in one thread.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Sequence

import can
import numpy as np
from numpy.typing import NDArray

from canbus.answers import AnswerCycles, Entry
from canbus.master.channel import (
    AnswerSlot,
    DataPlaneStats,
    ForceFrame,
    PatchChannel,
    SampleJob,
    Subscriber,
    rest_payload,
)
from canbus.master.frame_kinds import SERVICE_COB_IDS, SYNC
from canbus.master.publisher import Publisher
from canbus.master.rawsample import RawSubscriber
from canbus.master.syncpassage import Sync, SyncPassage
from skin.constants import TAXELS_PER_PATCH
from skin.errors import ConfigError

__all__ = ("DataPlane", "DataPlaneStats", "ForceFrame", "PatchChannel", "Subscriber")

logger = logging.getLogger(__name__)

PUBLISH_HOLD_S = 0.001
"""How long the publisher waits, after a patch's sample is ready, for the rest of the
cycle's patches to answer, so that it decodes and sends them in one round; it goes at
once when every online patch has answered (or broken off) or the cycle closes."""

MAX_BUS_LAG_S = 0.05
"""How long after a SYNC the data plane waits for the bus to show it passed before opening
its cycle anyway: far above a receive thread's lag on a busy machine, and only a bus that
carries no frame at all waits it out."""

class DataPlane(AnswerCycles[AnswerSlot], can.Listener):
    """Patch TPDOs -> forces -> force TPDOs on ``bus``; see the module docstring."""

    stats: DataPlaneStats
    _passage: SyncPassage

    def __init__(self, bus: can.BusABC, *, sync_window_s: float,
                 background: bool = True, max_bus_lag_s: float = MAX_BUS_LAG_S,
                 publish_hold_s: float = PUBLISH_HOLD_S) -> None:
        if not (math.isfinite(sync_window_s) and sync_window_s >= 0):
            raise ConfigError("sync_window_s", f"must be >= 0 s, got {sync_window_s}")
        if not (math.isfinite(max_bus_lag_s) and max_bus_lag_s >= 0):
            raise ConfigError("max_bus_lag_s", f"must be >= 0 s, got {max_bus_lag_s}")
        if not (math.isfinite(publish_hold_s) and publish_hold_s >= 0):
            raise ConfigError("publish_hold_s", f"must be >= 0 s, got {publish_hold_s}")
        super().__init__(sync_window_s, DataPlaneStats())
        self.bus = bus
        self.max_bus_lag_s = max_bus_lag_s
        self.publish_hold_s = publish_hold_s
        self.bus_traffic: frozenset[int] = SERVICE_COB_IDS
        """COB-IDs of the bus's own traffic beside the patches' PDOs: counted as
        ``bus_frames``, not unknown (``canbus.master.frame_kinds``)."""
        # self._lock (AnswerCycles'): the cycle state, held briefly by every thread
        self._publish_lock = threading.Lock()  # one publisher at a time, in queue order
        self._shapes: dict[object, int] = {}  # PDO layout and pillars -> slot key
        self._passage = SyncPassage()  # the SYNCs sent whose passage the bus has not shown
        self._queue: list[SampleJob] = []
        self._publisher = Publisher(bus, self.stats)
        self._wake = threading.Event()  # a sample is queued
        self._answered = threading.Event()  # ... and every patch has answered, or the cycle closed
        self._waiting = 0  # online patches whose answer to the open cycle is not over yet
        self._stopping = False
        self._thread: threading.Thread | None = None
        if background:
            self._thread = threading.Thread(target=self._run, name="dataplane", daemon=True)
            self._thread.start()

    # -- channels ---------------------------------------------------------------------------

    def add_channel(self, channel: PatchChannel, *, online: bool = True) -> None:
        """Add a patch, or replace it (its frames of the current cycle are forgotten);
        ``online=False``: see :meth:`set_online`."""
        if channel.pillars not in (1, 3):
            raise ConfigError("channel.pillars", f"must be 1 or 3, got {channel.pillars}")
        if not (math.isfinite(channel.lsb_ohm) and channel.lsb_ohm > 0):
            raise ConfigError("channel.lsb_ohm", f"must be > 0, got {channel.lsb_ohm}")
        _check_shape(channel.scale, (TAXELS_PER_PATCH, channel.pillars), "channel.scale")
        if not np.all(np.isfinite(channel.scale) & (np.asarray(channel.scale) > 0)):
            raise ConfigError("channel.scale", "must be finite and > 0")
        _check_shape(channel.masked, (TAXELS_PER_PATCH,), "channel.masked")
        shape = (tuple(layout.entries for layout in channel.codec.layouts), channel.pillars)
        with self._lock:
            slot = AnswerSlot(channel, self._shapes.setdefault(shape, len(self._shapes)))
            slot.online = online
            others = [s.channel for n, s in self._slots.items() if n != channel.node_id]
            _check_identifiers(channel, others)
            old = self._slots.pop(channel.node_id, None)
            if old is not None:
                old.active = False
            self._slots[channel.node_id] = slot
            self._rebuild_table()

    def set_online(self, node_id: int, online: bool) -> None:
        """Decode a patch's PDOs (``True``) or not: an offline patch (lost, configuring,
        stopped) still gets one sample per SYNC, every taxel ``MISSING``, and its frames
        count as unknown."""
        with self._lock:
            slot = self._slots.get(node_id)
            if slot is None:
                raise ConfigError("node_id", f"no channel for patch {node_id}")
            if slot.online != online:
                slot.online = online
                self._rebuild_table()

    def remove_channel(self, node_id: int) -> None:
        """Forget a patch: its frames are counted as unknown from now on."""
        with self._lock:
            slot = self._slots.pop(node_id, None)
            if slot is not None:
                slot.active = False
                self._rebuild_table()

    @property
    def steady_from_cycle(self) -> int | None:
        """The first cycle opened with every patch of the bus online (operational): its
        samples and the later ones are the steady state's (``stats.steady_samples``); None
        until then. Set up is over for good: a patch lost later counts against it."""
        return self._publisher.steady_from_cycle

    def channel(self, node_id: int) -> PatchChannel:
        try:
            return self._slots[node_id].channel
        except KeyError as err:
            raise ConfigError("node_id", f"no channel for patch {node_id}") from err

    def _rebuild_table(self) -> None:
        table: dict[int, Entry[AnswerSlot]] = {}
        for slot in self._slots.values():
            if slot.online:
                table.update(slot.entries())
        self._table = table  # read without the lock
        self._count_waiting()

    def _count_waiting(self) -> None:
        self._waiting = sum(slot.online and slot.active and not (slot.done or slot.ended)
                            for slot in self._slots.values())

    # -- the hot path: AnswerCycles.take (True for a channel's PDO; else _other) --------------

    def on_message_received(self, msg: can.Message) -> None:
        self.take(msg)

    def _other(self, msg: can.Message) -> bool:
        """Not a PDO of a channel: counted as the bus's own traffic or unknown."""
        # only the notifier thread writes these counters
        if msg.arbitration_id in self.bus_traffic and not msg.is_extended_id \
                and not msg.is_error_frame:
            self.stats.bus_frames += 1  # SYNC, heartbeats, SDO, ... (frame_kinds)
            if msg.arbitration_id == SYNC and self._passage and self.sync_echo:
                self._sync_echoed(msg.data[0] if msg.data else 0)
        else:
            self.stats.unknown_frames += 1
        return False

    def _sample(self, slot: AnswerSlot, cycle: Sync, missing: int, complete: bool) -> None:
        """Queue the slot's sample of the open cycle for the publisher (lock held)."""
        self._queue.append(SampleJob(slot, cycle, bytes(slot.raw), missing, complete))
        if complete and not self._wake.is_set():  # the publisher has not yet taken the queue
            self._wake.set()

    def _answer_over(self, slot: AnswerSlot) -> None:
        """The slot's answer to the open cycle is complete or broken off: once every online
        patch's is, the publisher goes at once rather than after ``publish_hold_s``."""
        if not (slot.done or slot.ended):
            self._waiting -= 1
            if self._waiting <= 0:
                self._answered.set()

    # -- cycles -----------------------------------------------------------------------------

    def on_sync(self, cycle: int, sync_counter: int, timestamp: float) -> None:
        """SYNC ``cycle`` passed on the bus at ``timestamp``: close the previous cycle (and
        any announced by :meth:`on_sync_sent` before it), open this one."""
        with self._lock:
            self._open_all(self._passage.passed_until(math.inf))
            self._open(cycle, sync_counter, timestamp)
        self._publish_now()

    def on_sync_sent(self, cycle: int, sync_counter: int, timestamp: float) -> None:
        """This host sends SYNC ``cycle`` at ``timestamp``: the open cycle closes when the bus
        shows it passed (module docstring), or at the latest ``max_bus_lag_s`` after it."""
        with self._lock:
            if self._cycle is None and not self._passage and not self.sync_echo:
                self._open(cycle, sync_counter, timestamp)
            else:
                self._passage.sent((cycle, sync_counter, timestamp))
                self._open_all(self._passage.passed_until(timestamp - self.max_bus_lag_s))
        self._publish_now()

    def _bus_passed(self, timestamp: float) -> None:
        """A frame stamped ``timestamp`` was taken: every SYNC sent before it has passed."""
        with self._lock:
            self._open_all(self._passage.passed_until(timestamp))
        self._publish_now()

    def _sync_echoed(self, counter: int) -> None:
        """The echo of the SYNC with ``counter``: the bus passed it (and any sent before it
        whose echo was lost) here; an echo of a SYNC opened already changes nothing."""
        with self._lock:
            passed = self._passage.echoed(counter)
            self._open_all(passed)
        if passed:
            self._publish_now()

    @property
    def sync_echo(self) -> bool:
        """The bus hands this data plane the echo of the SYNCs its host sends, with their
        counter (udp_multicast, SYNC not claimed): the echo, not a time stamp, is where the
        bus passed it."""
        return self._passage.by_echo

    @sync_echo.setter
    def sync_echo(self, value: bool) -> None:
        with self._lock:
            self._passage.by_echo = value

    def _open_all(self, syncs: list[Sync]) -> None:
        """Open each of ``syncs`` in turn, closing the cycle before it (lock held)."""
        for sync in syncs:
            self._open(*sync)

    def _opened(self, cycle: int) -> None:
        """Cycle ``cycle`` is open (lock held): every online patch is to answer it."""
        self._count_waiting()
        if self._publisher.steady_from_cycle is None and self._slots and all(
                slot.online and slot.active for slot in self._slots.values()):
            self._publisher.steady_from_cycle = cycle

    def answered(self) -> bool:
        """No cycle is open, or every patch that can still answer it has: a whole answer,
        or one broken off (offline and inactive channels answer nothing)."""
        with self._lock:
            return self._cycle is None or all(
                slot.done or slot.ended or not slot.active or not slot.online
                for slot in self._slots.values())

    def flush(self) -> None:
        """Close the current cycle now and publish everything queued before returning."""
        with self._lock:
            self._open_all(self._passage.passed_until(math.inf))
            self._end_cycles()
        self.publish_pending()

    # -- publishing -------------------------------------------------------------------------

    def subscribe(self, callback: Subscriber) -> None:
        """Call ``callback(frames)`` with each published batch (from the publishing thread;
        see :mod:`canbus.master.publisher`)."""
        self._publisher.subscribe(callback)

    def unsubscribe(self, callback: Subscriber) -> None:
        self._publisher.unsubscribe(callback)

    def subscribe_raw(self, callback: RawSubscriber) -> None:
        """Call ``callback(samples)`` with each published batch's resistances as the patches
        sent them (:mod:`canbus.master.rawsample`)."""
        self._publisher.subscribe_raw(callback)

    def unsubscribe_raw(self, callback: RawSubscriber) -> None:
        self._publisher.unsubscribe_raw(callback)

    def tare(self, node_id: int) -> None:
        """Re-zero patch ``node_id``'s baseline at its last complete sample.

        Raises :class:`~canbus.master.baseline.PatchLoadedError` while it is loaded (or
        before its first complete sample), ConfigError if it has no channel or baseline.
        """
        channel = self.channel(node_id)
        if channel.baseline is None:
            raise ConfigError("node_id", f"patch {node_id} has no baseline to tare")
        self._publisher.tare(channel)

    def raw_sample(self, node_id: int) -> NDArray[np.float64] | None:
        """The last complete ``(9, P)`` resistances of a patch in ohm, before ``scale``."""
        return self._publisher.raw_sample(node_id)

    def publish_pending(self) -> None:
        """Decode and publish every queued sample, in the order they were queued."""
        with self._publish_lock:
            with self._lock:
                jobs, self._queue = self._queue, []
            if jobs:
                self._publisher.publish(jobs)

    def warm_up(self) -> None:
        """Run every channel's publishing path once on a sample at rest, sending nothing,
        so that the first cycle does not pay for code and tables run the first time."""
        with self._publish_lock:
            with self._lock:
                slots = list(self._slots.values())
            self._publisher.warm_up([SampleJob(slot, (0, 0, 0.0), rest_payload(slot), 0, False)
                                     for slot in slots])

    def stop(self) -> None:
        """Stop the publishing thread after it published what is queued (``can.Listener``)."""
        thread, self._thread = self._thread, None
        if thread is not None:
            self._stopping = True
            self._wake.set()
            self._answered.set()
            thread.join()
        self.publish_pending()

    def _publish_now(self) -> None:
        if self._thread is None:
            self.publish_pending()
        elif self._queue:  # a wake-up with nothing to publish costs the next cycle a switch
            self._answered.set()
            self._wake.set()

    def _run(self) -> None:
        while not self._stopping:
            self._wake.wait()
            self._wake.clear()
            # One round per cycle where the patches answer close together: each round
            # costs its numpy calls whatever its size (docs/dataplane.md).
            self._answered.wait(self.publish_hold_s)
            self._answered.clear()
            try:
                self.publish_pending()
            except Exception:  # keep publishing: one bad batch must not stop the data plane
                logger.exception("data plane: publishing failed")


def _check_shape(array: NDArray[np.generic], shape: tuple[int, ...], name: str) -> None:
    a = np.asarray(array)
    try:
        np.broadcast_to(a, shape)
    except ValueError as err:
        raise ConfigError(name, f"must broadcast to {shape}, got {a.shape}") from err


def _check_identifiers(channel: PatchChannel, others: Sequence[PatchChannel]) -> None:
    """No two patches share a PDO COB-ID, and no force node sends on a patch's PDO COB-ID."""
    mine = set(channel.codec.cob_ids.tolist())
    force = channel.force_node.cob_ids()
    for other in others:
        theirs = set(other.codec.cob_ids.tolist())
        clash = (mine & theirs) or (mine & other.force_node.cob_ids()) or (force & theirs)
        if clash:
            raise ConfigError("channel", f"patch {channel.node_id} and patch {other.node_id} "
                              f"share COB-ID(s) {', '.join(f'0x{c:03X}' for c in sorted(clash))}")
    if mine & force:
        raise ConfigError("channel", f"patch {channel.node_id}'s force node sends on its own "
                          f"PDO COB-ID(s) {sorted(mine & force)}")
