"""The data plane: patch TPDOs in, forces out, one SYNC cycle at a time.

One ``can.Listener`` takes every frame on the bus. Its hot path looks the COB-ID up in a
table (COB-ID -> channel slot, PDO position), checks the frame against the open SYNC
cycle and copies the payload into that slot's preallocated buffer; nothing else happens
per frame. When every PDO of a patch has arrived exactly once, the patch's payload is
queued; the publisher decodes what is queued in numpy batches (one ``PdoCodec.unpack``
per PDO layout, one ``decode`` per decoder object) and sends the force nodes' TPDOs
with ``bus.send``.

Cycle rules. A patch answers SYNC k with one *answer*: its synchronous TPDOs, sent
together in a fixed order (:attr:`PatchChannel.answer_order`; by default ascending COB-ID,
the order in which one node's queued frames win arbitration on a CAN bus). A frame
counts for cycle k only if its timestamp lies in [t_k, t_k + sync_window_s] (CiA 301's
synchronous window, object 0x1007; t_k is the time the host sent SYNC k;
``sync_window_s == 0`` means until the next SYNC) *and* it belongs to the answer that
began in that window:

- the answer begins with its first TPDO; a later TPDO seen before it is the tail of an
  earlier answer and counts as ``late``, as does a frame stamped before t_k;
- the answer's TPDOs must then come one after the other, in order; any other frame of
  the patch ends the answer: a ``duplicate`` if its PDO was already seen (that PDO is
  not trusted either), ``out_of_order`` if it is ahead of its place (the frame before it
  was lost). Nothing after the end of an answer counts for the cycle, so the PDOs from
  the break on are missing. One exception: the frame just taken, again with the same
  bytes, is counted a ``duplicate`` and changes nothing (a CAN receiver gets a frame
  twice when an error in its last bit makes the sender retransmit it);
- a frame shorter than its mapping is ``malformed``: that PDO is not trusted.

So a sample is complete only when every TPDO of one answer arrived once, in order, in
the window; an incomplete sample carries an unbroken run of one answer from its first
TPDO; and the data of two answers is never mixed, however late, duplicated or reordered
the frames come, unless a whole answer's worth of consecutive frames was lost (what
classic CAN cannot prove, and what a one-cycle-stale answer looks like, is in
docs/host.md). Frames stamped after the window are held until the next SYNC, which
takes the ones inside its own window (a patch may answer SYNC k+1 before the host has
called :meth:`DataPlane.on_sync`) and counts the rest ``late``.

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

import dataclasses
import logging
import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import can
import numpy as np
from numpy.typing import NDArray

from canbus.codes import code_to_resistance
from canbus.master.baseline import Baseline
from canbus.master.forcenode import ForceNode, batch_frames
from canbus.pdo_codec import PdoCodec
from canbus.txmessage import TxMessage
from decoder.protocol import Decoder
from decoder.reasons import Reason
from skin.constants import DEFAULT_CONSTANTS, TAXELS_PER_PATCH
from skin.errors import ConfigError

logger = logging.getLogger(__name__)

RESISTANCES, ANSWERED = 0x2000, 0x2006


@dataclass(frozen=True)
class ForceFrame:
    """One patch's forces for one SYNC cycle."""

    patch: int  # patch node-ID
    force_node: int  # force node-ID it was published as
    cycle: int  # host's SYNC cycle number (1, 2, ...), monotonic
    sync_counter: int  # the SYNC counter byte sent (0 without a counter)
    timestamp: float  # time.time() when the host sent that SYNC
    force_N: NDArray[np.float64]  # (9, 3) Fx, Fy, Fz; 0 N where not valid
    valid: NDArray[np.bool_]  # (9,)
    reason: NDArray[np.uint8]  # (9,) decoder.reasons codes; MISSING, FAULTY from the data plane
    complete: bool  # every TPDO of one answer of the patch arrived, in order, in the window
    published: bool  # the force TPDOs went onto the bus


@dataclass
class PatchChannel:
    """Everything the data plane needs to turn one patch's PDOs into forces."""

    node_id: int
    codec: PdoCodec  # the patch's TPDOs as configured (maps 0x2000 codes; may map more)
    pillars: int  # 1 (z-only) or 3
    lsb_ohm: float  # the patch's 0x2001
    decoder: Decoder  # any registered decoder; r0 baked in by the host
    force_node: ForceNode
    scale: NDArray[np.float64] = field(default_factory=lambda: np.ones((TAXELS_PER_PATCH, 1)))
    """(9, P), or anything that broadcasts to it: multiplied onto resistances before decode
    (with a ``baseline``, its scale is used instead)."""
    masked: NDArray[np.bool_] = field(
        default_factory=lambda: np.zeros(TAXELS_PER_PATCH, dtype=bool))
    """(9,) taxels the host knows are faulty: invalid with ``Reason.FAULTY``."""
    baseline: Baseline | None = None
    """Tare and drift tracking: the data plane decodes with its scale, tracks drift on every
    complete sample and tares it (:meth:`DataPlane.tare`)."""
    answer_order: str = "cob-id"
    """The order in which the patch sends the TPDOs of one answer: ``"cob-id"`` (ascending
    identifier, as a node's queued frames leave on a CAN bus) or ``"tpdo"`` (TPDO number
    order, a device with a single FIFO transmit buffer)."""


@dataclass
class DataPlaneStats:
    """Counters since the data plane was built."""

    frames_in: int = 0  # PDO frames of known channels
    frames_out: int = 0  # force TPDOs sent
    unknown_frames: int = 0  # anything not a PDO of a channel (other services, lost patches)
    duplicate_frames: int = 0  # a PDO already seen in its cycle
    late_frames: int = 0  # before the window, after it, or the tail of an earlier answer
    out_of_order_frames: int = 0  # ahead of its place in the answer, or after the answer ended
    second_answers: int = 0  # an answer began after a complete one in one window: the one
    # published was then most likely the previous SYNC's, whole (docs/host.md)
    stale_answers: int = 0  # an answer that names (0x2006) an earlier SYNC than its cycle's
    malformed_frames: int = 0  # shorter than the PDO's mapping
    samples: int = 0
    batches: int = 0  # publishing rounds: samples / batches is the mean decode batch
    complete_samples: int = 0
    incomplete_samples: int = 0
    decode_errors: int = 0  # decoder raised: those samples are dropped (logged)
    send_errors: int = 0  # bus.send raised: that sample is not published (logged)
    callback_errors: int = 0  # a subscriber raised (logged)

    def snapshot(self) -> dict[str, int]:
        return dataclasses.asdict(self)


class _Slot:
    """A channel's state in the current cycle and its precomputed layout."""

    def __init__(self, channel: PatchChannel, key: int) -> None:
        codec = channel.codec
        pdos = len(codec.layouts)
        self.channel = channel
        self.active = True
        self.online = True
        self.stride = codec.width + codec.width % 2  # bytes per PDO in ``raw``: even, so
        self.raw = bytearray(self.stride * pdos)  # that codes read as UNSIGNED16 words
        self.zeros = bytes(self.stride * pdos)
        self.full = (1 << pdos) - 1
        self.seen = 0  # PDO bits received this cycle
        self.bad = 0  # PDO bits not trusted this cycle (duplicate, malformed)
        self.done = False  # queued this cycle
        self.next = 0  # the place in the answer the next frame must take (0: not begun)
        self.ended = False  # the answer was broken: nothing more counts this cycle
        self.key = key  # channels with equal keys are unpacked together
        cob_ids = codec.cob_ids.tolist()
        if channel.answer_order == "cob-id":
            order = sorted(range(pdos), key=cob_ids.__getitem__)
        elif channel.answer_order == "tpdo":
            order = list(range(pdos))
        else:
            raise ConfigError("channel.answer_order", "must be 'cob-id' or 'tpdo', got "
                              f"{channel.answer_order!r}")
        self.place = [0] * pdos  # PDO position in codec.layouts -> its place in the answer
        for n, p in enumerate(order):
            self.place[p] = n
        p = channel.pillars
        try:
            self.columns = np.array([[codec.column(RESISTANCES, 3 * t + k + 1) for k in range(p)]
                                     for t in range(TAXELS_PER_PATCH)], dtype=np.intp)
        except ValueError as err:
            raise ConfigError("channel.codec", f"patch {channel.node_id}'s PDOs do not map "
                              f"every 0x2000 code of {p} pillar(s)") from err
        carried = np.zeros((pdos, TAXELS_PER_PATCH), dtype=bool)
        at: dict[tuple[int, int], int] = {}  # variable -> its first byte in ``raw``
        for n, layout in enumerate(codec.layouts):
            offset = self.stride * n
            for entry in layout.entries:
                at.setdefault((entry.index, entry.subindex), offset)
                offset += entry.bits // 8
                value = entry.subindex - 1
                if entry.index == RESISTANCES and value % 3 < p:
                    carried[n, value // 3] = True
        self.carried = carried  # (PDOs, 9): the taxels each PDO carries
        offsets = np.array([[at[(RESISTANCES, 3 * t + k + 1)] for k in range(p)]
                            for t in range(TAXELS_PER_PATCH)], dtype=np.intp)
        self.words: NDArray[np.intp] | None = None
        """(9, P) each code's place in ``raw`` read as little-endian UNSIGNED16 words, or
        None if a code starts at an odd byte (then ``codec.unpack`` reads them)."""
        u16 = all(codec.dtypes[c] == np.dtype("<u2") for c in self.columns.ravel().tolist())
        if u16 and not np.any(offsets % 2):
            self.words = offsets // 2
        self.answered_bit = 0  # the PDO that carries 0x2006, the SYNC counter answered
        self.answered_at = 0  # its byte in that PDO
        if (ANSWERED, 0) in at:
            pdo, self.answered_at = divmod(at[(ANSWERED, 0)], self.stride)
            self.answered_bit = 1 << pdo

    def taxels_of(self, pdo_bits: int) -> NDArray[np.bool_]:
        """(9,) the taxels carried by the PDOs whose bits are set."""
        which = np.array([pdo_bits >> p & 1 for p in range(len(self.carried))], dtype=bool)
        taxels: NDArray[np.bool_] = self.carried[which].any(axis=0)
        return taxels

    def reset(self) -> None:
        self.seen = self.bad = self.next = 0
        self.done = self.ended = False
        self.raw[:] = self.zeros


@dataclass(frozen=True)
class _Job:
    slot: _Slot
    cycle: tuple[int, int, float]
    payload: bytes
    missing: int  # PDO bits absent or not trusted
    complete: bool


_Entry = tuple[_Slot, int, int, int, int]  # slot, PDO bit, byte offset, mapped size, place
Subscriber = Callable[[list[ForceFrame]], None]


class DataPlane(can.Listener):
    """Patch TPDOs -> forces -> force TPDOs on ``bus``; see the module docstring."""

    def __init__(self, bus: can.BusABC, *, sync_window_s: float,
                 background: bool = True) -> None:
        if not (math.isfinite(sync_window_s) and sync_window_s >= 0):
            raise ConfigError("sync_window_s", f"must be >= 0 s, got {sync_window_s}")
        self.bus = bus
        self.sync_window_s = sync_window_s
        self.stats = DataPlaneStats()
        self._lock = threading.Lock()  # cycle state: held briefly by every thread
        self._publish_lock = threading.Lock()  # one publisher at a time, in queue order
        self._table: dict[int, _Entry] = {}  # replaced, never mutated: read without the lock
        self._slots: dict[int, _Slot] = {}
        self._shapes: dict[object, int] = {}  # PDO layout and pillars -> slot key
        self._cycle: tuple[int, int, float] | None = None
        self._start, self._end = math.inf, -math.inf  # no cycle open
        self._held: list[tuple[_Entry, bytes, float]] = []
        self._queue: list[_Job] = []
        self._subscribers: tuple[Subscriber, ...] = ()
        self._raw_samples: dict[int, NDArray[np.float64]] = {}
        self._last_complete: dict[int, ForceFrame] = {}
        self._wake = threading.Event()
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
            slot = _Slot(channel, self._shapes.setdefault(shape, len(self._shapes)))
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

    def channel(self, node_id: int) -> PatchChannel:
        try:
            return self._slots[node_id].channel
        except KeyError as err:
            raise ConfigError("node_id", f"no channel for patch {node_id}") from err

    def _rebuild_table(self) -> None:
        table: dict[int, _Entry] = {}
        for slot in self._slots.values():
            if not slot.online:
                continue
            codec = slot.channel.codec
            for p, (cob, size) in enumerate(zip(codec.cob_ids.tolist(), codec.sizes.tolist(),
                                                strict=True)):
                table[cob] = (slot, 1 << p, slot.stride * p, size, slot.place[p])
        self._table = table

    # -- the hot path -----------------------------------------------------------------------

    def on_message_received(self, msg: can.Message) -> None:
        self.take(msg)

    def take(self, msg: can.Message) -> bool:
        """Handle ``msg`` if it is a PDO of a channel; False (and counted unknown) if not."""
        entry = self._table.get(msg.arbitration_id)
        if entry is None or msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame:
            self.stats.unknown_frames += 1  # only the notifier thread writes this counter
            return False
        with self._lock:
            self.stats.frames_in += 1
            if self._start <= msg.timestamp <= self._end:
                self._accept(entry, msg.data)
            elif msg.timestamp > self._end and len(self._held) < 2 * len(self._table):
                self._held.append((entry, bytes(msg.data), msg.timestamp))
            else:
                self.stats.late_frames += 1
        return True

    def _accept(self, entry: _Entry, data: bytes | bytearray) -> None:
        """One in-window frame: it extends the cycle's answer or is turned away (lock held)."""
        slot, bit, offset, size, place = entry
        if bit == slot.answered_bit and self._stale(slot, data):
            return
        if place != slot.next or slot.ended or slot.done:
            self._turn_away(entry, data)
            return
        slot.seen |= bit
        slot.next = place + 1
        if len(data) < size:
            self.stats.malformed_frames += 1
            slot.bad |= bit
            return
        slot.raw[offset:offset + size] = data if len(data) == size else data[:size]
        if slot.seen == slot.full and not slot.bad and slot.active and self._cycle is not None:
            slot.done = True
            self._queue.append(_Job(slot, self._cycle, bytes(slot.raw), 0, True))
            if not self._wake.is_set():  # the publisher has not yet taken the queue
                self._wake.set()

    def _stale(self, slot: _Slot, data: bytes | bytearray) -> bool:
        """The PDO names the SYNC it answers (0x2006), and it is not this cycle's: an answer
        to an earlier SYNC, counted ``stale_answers`` and ``late_frames`` (lock held)."""
        counter = self._cycle[1] if self._cycle is not None else 0
        if not counter or len(data) <= slot.answered_at or data[slot.answered_at] == counter:
            return False
        self.stats.stale_answers += 1
        self.stats.late_frames += 1
        return True

    def _turn_away(self, entry: _Entry, data: bytes | bytearray) -> None:
        """A frame that does not extend the cycle's answer (module docstring; lock held)."""
        slot, bit, offset, size, place = entry
        stats = self.stats
        if not slot.next and not slot.ended:
            stats.late_frames += 1  # the tail of an earlier answer
        elif not slot.seen & bit:
            stats.out_of_order_frames += 1
            slot.ended = True
        else:
            stats.duplicate_frames += 1
            if slot.done and not place:
                stats.second_answers += 1
            # The frame just taken, again with the same bytes: a CAN receiver can get a
            # frame twice when its sender retransmits after an error in the last bit.
            repeat = place == slot.next - 1 and slot.raw[offset:offset + size] == data[:size]
            if not (repeat or slot.done or slot.ended):
                slot.bad |= bit
                slot.ended = True

    # -- cycles -----------------------------------------------------------------------------

    def on_sync(self, cycle: int, sync_counter: int, timestamp: float) -> None:
        """SYNC ``cycle`` was sent at ``timestamp``: close the previous cycle, open this one."""
        with self._lock:
            self._close()
            self._cycle = (cycle, sync_counter, timestamp)
            self._start = timestamp
            self._end = timestamp + self.sync_window_s if self.sync_window_s else math.inf
            held, self._held = self._held, []
            for entry, data, t in held:
                if self._start <= t <= self._end:
                    self._accept(entry, data)
                else:
                    self.stats.late_frames += 1
        self._publish_now()

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
            self._close()
            self._cycle = None
            self._start, self._end = math.inf, -math.inf
        self.publish_pending()

    def _close(self) -> None:
        """Queue the open cycle's unfinished patches as incomplete samples (lock held)."""
        if self._cycle is not None:
            for slot in self._slots.values():
                if not slot.done:
                    missing = slot.full & ~(slot.seen & ~slot.bad)
                    self._queue.append(_Job(slot, self._cycle, bytes(slot.raw), missing, False))
        for slot in self._slots.values():
            slot.reset()

    # -- publishing -------------------------------------------------------------------------

    def subscribe(self, callback: Subscriber) -> None:
        """Call ``callback(frames)`` with each published batch (from the publishing thread)."""
        with self._lock:
            self._subscribers = (*self._subscribers, callback)

    def unsubscribe(self, callback: Subscriber) -> None:
        with self._lock:
            self._subscribers = tuple(c for c in self._subscribers if c != callback)

    def tare(self, node_id: int) -> None:
        """Re-zero patch ``node_id``'s baseline at its last complete sample.

        Raises :class:`~canbus.master.baseline.PatchLoadedError` while it is loaded (or
        before its first complete sample), ConfigError if it has no channel or baseline.
        """
        baseline = self.channel(node_id).baseline
        if baseline is None:
            raise ConfigError("node_id", f"patch {node_id} has no baseline to tare")
        last = self._last_complete.get(node_id)
        baseline.tare(self.raw_sample(node_id), None if last is None else last.force_N,
                      None if last is None else last.valid, node_id=node_id)

    def raw_sample(self, node_id: int) -> NDArray[np.float64] | None:
        """The last complete ``(9, P)`` resistances of a patch in ohm, before ``scale``."""
        sample = self._raw_samples.get(node_id)
        return None if sample is None else sample.copy()

    def publish_pending(self) -> None:
        """Decode and publish every queued sample, in the order they were queued."""
        with self._publish_lock:
            with self._lock:
                jobs, self._queue = self._queue, []
            if jobs:
                self._publish(jobs)

    def warm_up(self) -> None:
        """Run every channel's publishing path once on a sample at rest, sending nothing,
        so that the first cycle does not pay for code and tables run the first time."""
        with self._publish_lock:
            jobs = [_Job(slot, (0, 0, 0.0), _rest_payload(slot), 0, False)
                    for slot in list(self._slots.values())]
            if not jobs:
                return
            resistance = self._resistances(jobs, np.zeros((len(jobs), TAXELS_PER_PATCH), bool))
            for rows, decoder in _by_decoder(jobs):
                pillars = jobs[rows[0]].slot.channel.pillars
                result = decoder.decode(resistance[rows, :, :pillars])
                nodes = [jobs[i].slot.channel.force_node for i in rows]
                batch_frames(nodes, result.force_N, result.valid, np.zeros(len(rows), bool),
                             result.reason, 0)
                for node in nodes:
                    node.clear_sample()  # an SDO read shows "no value" until the first one

    def stop(self) -> None:
        """Stop the publishing thread after it published what is queued (``can.Listener``)."""
        thread, self._thread = self._thread, None
        if thread is not None:
            self._stopping = True
            self._wake.set()
            thread.join()
        self.publish_pending()

    def _publish_now(self) -> None:
        if self._thread is None:
            self.publish_pending()
        elif self._queue:  # a wake-up with nothing to publish costs the next cycle a switch
            self._wake.set()

    def _run(self) -> None:
        while not self._stopping:
            self._wake.wait()
            self._wake.clear()
            try:
                self.publish_pending()
            except Exception:  # keep publishing: one bad batch must not stop the data plane
                logger.exception("data plane: publishing failed")

    def _publish(self, jobs: list[_Job]) -> None:
        n = len(jobs)
        missing = np.zeros((n, TAXELS_PER_PATCH), dtype=bool)
        masked = np.zeros((n, TAXELS_PER_PATCH), dtype=bool)
        for i, job in enumerate(jobs):
            if job.missing:
                missing[i] = job.slot.taxels_of(job.missing)
            masked[i] = job.slot.channel.masked
        resistance = self._resistances(jobs, missing | masked)
        force = np.zeros((n, TAXELS_PER_PATCH, 3))
        reason = np.zeros((n, TAXELS_PER_PATCH), dtype=np.uint8)
        decoded = np.zeros(n, dtype=bool)
        for rows, decoder in _by_decoder(jobs):
            try:
                pillars = jobs[rows[0]].slot.channel.pillars
                result = decoder.decode(resistance[rows, :, :pillars])
            except Exception:
                logger.exception("data plane: %r failed on patches %s", decoder,
                                 [jobs[i].slot.channel.node_id for i in rows])
                self.stats.decode_errors += len(rows)
                continue
            force[rows] = result.force_N
            reason[rows] = result.reason
            decoded[rows] = True
        reason[missing] = Reason.MISSING
        reason[masked] = Reason.FAULTY
        valid = reason == 0
        force[~valid] = 0.0
        if decoded.all():
            self._send(jobs, force, valid, reason)
        else:
            kept = np.flatnonzero(decoded)
            self._send([jobs[i] for i in kept], force[kept], valid[kept], reason[kept])

    def _resistances(self, jobs: Sequence[_Job],
                     undecodable: NDArray[np.bool_]) -> NDArray[np.float64]:
        """``(n, 9, 3)``: each job's ``(9, P)`` ohms in ``[:, :, :P]``, scaled, NaN where
        ``undecodable``; one unpack per layout.

        NaN, not a stale or faulty reading, so that a decoder that couples taxels (deconv)
        treats those taxels as invalid rather than spreading them to their neighbours.
        """
        out = np.full((len(jobs), TAXELS_PER_PATCH, 3), np.nan)
        groups: dict[int, list[int]] = {}
        for i, job in enumerate(jobs):
            groups.setdefault(job.slot.key, []).append(i)
        for rows in groups.values():
            first = jobs[rows[0]].slot
            blob = b"".join(jobs[i].payload for i in rows)
            if first.words is not None:
                codes = np.frombuffer(blob, dtype="<u2").reshape(len(rows), -1)[:, first.words]
            else:
                codec = first.channel.codec
                payload = np.frombuffer(blob, dtype=np.uint8).reshape(
                    len(rows), len(codec.layouts), first.stride)[:, :, :codec.width]
                codes = codec.unpack(payload)[:, first.columns]
            channels = [jobs[i].slot.channel for i in rows]
            lsb = {channel.lsb_ohm for channel in channels}
            if len(lsb) == 1:  # open/saturated: +inf
                raw = code_to_resistance(codes, lsb.pop())
            else:
                raw = code_to_resistance(codes, 1.0) * np.array(
                    [channel.lsb_ohm for channel in channels])[:, None, None]
            for m, i in enumerate(rows):
                if jobs[i].complete:
                    self._raw_samples[channels[m].node_id] = raw[m]
            shape = raw.shape[1:]
            scales = [channel.scale if channel.baseline is None else channel.baseline.scale
                      for channel in channels]
            if all(np.shape(scale_) == shape for scale_ in scales):
                scale = np.array(scales, dtype=np.float64)
            else:
                scale = np.empty_like(raw)
                for m, scale_ in enumerate(scales):
                    scale[m] = scale_  # broadcast to (9, P)
            scaled = raw * scale
            scaled[undecodable[rows]] = np.nan
            out[rows, :, : first.channel.pillars] = scaled
        return out

    def _send(self, jobs: list[_Job], force: NDArray[np.float64], valid: NDArray[np.bool_],
              reason: NDArray[np.uint8]) -> None:
        if not jobs:
            return
        complete = [job.complete for job in jobs]
        nodes = [job.slot.channel.force_node for job in jobs]
        frames = batch_frames(nodes, force, valid, np.array(complete), reason,
                              [job.cycle[1] for job in jobs])
        # Every frame onto the bus first: the frames for the API come after.
        published = [node.transmitting and self._transmit(f, _bus_of(node, self.bus))
                     for node, f in zip(nodes, frames, strict=True)]
        out = []
        for i, job in enumerate(jobs):
            cycle, counter, timestamp = job.cycle
            out.append(ForceFrame(job.slot.channel.node_id, nodes[i].node_id, cycle, counter,
                                  timestamp, force[i], valid[i], reason[i], job.complete,
                                  published[i]))
        self._follow_baselines(out)
        stats = self.stats
        stats.samples += len(out)
        stats.batches += 1
        stats.complete_samples += sum(complete)
        stats.incomplete_samples += len(out) - sum(complete)
        for callback in self._subscribers:
            try:
                callback(out)
            except Exception:
                stats.callback_errors += 1
                logger.exception("data plane: subscriber %r failed", callback)

    def _follow_baselines(self, frames: list[ForceFrame]) -> None:
        """Remember each patch's last complete sample (for tare) and track drift on it."""
        for out in frames:
            if not out.complete:
                continue
            previous = self._last_complete.get(out.patch)
            self._last_complete[out.patch] = out
            baseline = self._slots[out.patch].channel.baseline if out.patch in self._slots \
                else None
            raw = self._raw_samples.get(out.patch)
            if baseline is None or baseline.time_constant_s is None or raw is None:
                continue
            dt = out.timestamp - previous.timestamp if previous is not None else 0.0
            baseline.track(raw, out.force_N, out.valid, max(dt, 0.0))

    def _transmit(self, frames: list[tuple[int, bytes]], bus: can.BusABC) -> bool:
        send, frame, sent = bus.send, TxMessage.frame, 0
        try:
            for cob, payload in frames:
                send(frame(cob, payload))
                sent += 1
        except can.CanError as err:
            self.stats.send_errors += 1
            logger.warning("data plane: force TPDO not sent: %s", err)
            return False
        finally:
            self.stats.frames_out += sent
        return True


class PdoRouter(can.Listener):
    """A notifier's one listener: a PDO of a data plane channel goes to the data plane
    alone, every other frame to ``others`` in order (canopen's listener, a SYNC follower).

    canopen has no use for the patches' PDOs once the data plane owns them, and its
    listener costs a microsecond a frame on the latency path.
    """

    def __init__(self, dataplane: DataPlane, others: Sequence[can.Listener]) -> None:
        self.dataplane = dataplane
        self.take = dataplane.take
        self.others = tuple(others)

    def on_message_received(self, msg: can.Message) -> None:
        if not self.take(msg):
            for listener in self.others:
                listener.on_message_received(msg)

    def on_error(self, exc: Exception) -> None:
        """As ``can.Notifier`` does: handled if any of ``others`` handles it."""
        handled = False
        for listener in self.others:
            try:
                listener.on_error(exc)
            except NotImplementedError:
                continue
            handled = True
        if not handled:
            raise NotImplementedError

    def stop(self) -> None:
        """Stop every listener, the data plane last (it publishes what is queued)."""
        for listener in self.others:
            listener.stop()
        self.dataplane.stop()


def _rest_payload(slot: _Slot) -> bytes:
    """The slot's raw bytes with every code at the decoder's zero-force resistance."""
    channel = slot.channel
    codec = channel.codec
    values = np.zeros((1, len(codec.variables)))
    rest = (channel.baseline.r0_ref if channel.baseline is not None else
            np.broadcast_to(DEFAULT_CONSTANTS.nominal_resistance_ohm[:channel.pillars],
                            (TAXELS_PER_PATCH, channel.pillars)))
    codes = np.clip(np.rint(rest / channel.lsb_ohm), 1, 0xFFFD)
    values[0, slot.columns.ravel()] = codes.ravel()
    packed = codec.pack(values)[0]  # (PDOs, width)
    raw = bytearray(slot.stride * len(codec.layouts))
    for p in range(len(codec.layouts)):
        raw[slot.stride * p:slot.stride * p + codec.width] = packed[p].tobytes()
    return bytes(raw)


def _bus_of(node: ForceNode, default: can.BusABC) -> can.BusABC:
    """The bus a force node publishes on: the one it is attached to (several buses)."""
    network = node.network
    bus = network.bus if network is not None else None
    return bus if bus is not None else default


def _by_decoder(jobs: Sequence[_Job]) -> list[tuple[list[int], Decoder]]:
    """Rows that share one decoder object and pillar count: one decode call each."""
    groups: dict[tuple[int, int], tuple[list[int], Decoder]] = {}
    for i, job in enumerate(jobs):
        channel = job.slot.channel
        key = (id(channel.decoder), channel.pillars)
        groups.setdefault(key, ([], channel.decoder))[0].append(i)
    return list(groups.values())


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
