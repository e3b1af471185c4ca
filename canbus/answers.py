"""A patch's answers to SYNC, one sample per patch per cycle: the one rule by which every
reader of the patches' PDOs judges them (the live host's data plane, a listen-only host and
so ``skin decode``, the sniffer, the view's raw resistances).

A patch answers SYNC k with one *answer*: its synchronous TPDOs, sent together in a fixed
order (:attr:`PatchAnswer.place`; by default ascending COB-ID, the order in which one
node's queued frames win arbitration on a CAN bus). A frame counts for cycle k only if its
timestamp lies in [t_k, t_k + sync_window_s] (CiA 301's synchronous window, object 0x1007;
t_k is the time of SYNC k, as the host sent it or as a listener heard it;
``sync_window_s == 0`` means until the next SYNC) *and* it belongs to the answer that began
in that window:

- the answer begins with its first TPDO; a later TPDO seen before it is the tail of an
  earlier answer and counts as ``late``, as does a frame stamped before t_k;
- the answer's TPDOs must then come one after the other, in order; any other frame of
  the patch ends the answer: a ``duplicate`` if its PDO was already seen (that PDO is
  not trusted either), ``out_of_order`` if it is ahead of its place (the frame before it
  was lost). Nothing after the end of an answer counts for the cycle, so the PDOs from
  the break on are missing. One exception: the frame just taken, again with the same
  bytes, is counted a ``duplicate`` and changes nothing (a CAN receiver gets a frame
  twice when an error in its last bit makes the sender retransmit it);
- a frame shorter than its mapping is ``malformed``: that PDO is not trusted;
- where the mapping carries 0x2006 (the SYNC counter the patch answers), an answer that
  names another SYNC than the open cycle's is ``stale`` (and ``late``).

So a sample is complete only when every TPDO of one answer arrived once, in order, in
the window; an incomplete sample carries an unbroken run of one answer from its first
TPDO; and the data of two answers is never mixed, however late, duplicated or reordered
the frames come, unless a whole answer's worth of consecutive frames was lost (what
classic CAN cannot prove, and what a one-cycle-stale answer looks like, is in
docs/host.md). Frames stamped after the window are held until the next SYNC, which
takes the ones inside its own window (a patch may answer SYNC k+1 before its cycle was
opened) and counts the rest ``late``.

A complete answer is handed on at once (:meth:`AnswerCycles._sample`); every other patch's
when the next SYNC closes the cycle, incomplete, with the PDOs missing or not trusted. So
each patch gets exactly one sample per cycle, and a consumer can count cycles.

:class:`AnswerCycles` holds the open cycle and every patch's answer to it, and opens no
cycle by itself: the live host's data plane (:mod:`canbus.master.dataplane`) opens one where
the bus passed the SYNC it sent (or at once for one it heard); a reader of a bus or a
recording (:mod:`canbus.tools.answer_reader`) opens one at each SYNC in the bus's order.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from typing import Generic, Protocol, TypeVar

import can

from canbus.pdo_codec import TpdoLayout
from skin.errors import ConfigError

SYNC_COB_ID = 0x080
ANSWERED = 0x2006
"""The object a patch may map to name the SYNC (its counter byte) it answers."""
ANSWER_ORDERS = ("cob-id", "tpdo")

Cycle = tuple[int, int, float]
"""A SYNC cycle: its number (1, 2, ...), the SYNC's counter byte (0 without), its time."""
Slot = TypeVar("Slot", bound="PatchAnswer")
Entry = tuple[Slot, int, int, int, int]
"""A TPDO's place in its patch's answer: the answer, PDO bit, byte offset in ``raw``,
mapped size, place in the sending order."""


def counter_of_sync(msg: can.Message) -> int | None:
    """The counter byte of a SYNC (0 without one); None if ``msg`` is no SYNC (CiA 301: a
    standard data frame on 0x080 with no data or one counter byte)."""
    if msg.arbitration_id != SYNC_COB_ID or msg.is_extended_id or msg.is_remote_frame \
            or msg.is_error_frame or len(msg.data) > 1:
        return None
    return msg.data[0] if msg.data else 0


class AnswerCounters(Protocol):
    """The counters :class:`AnswerCycles` moves (the data plane's stats have them too)."""

    frames_in: int
    late_frames: int
    duplicate_frames: int
    out_of_order_frames: int
    second_answers: int
    stale_answers: int
    malformed_frames: int


class Passage(Protocol):
    """Where the bus passed a SYNC its owner sent (:mod:`canbus.master.syncpassage`)."""

    next_t: float
    """A frame stamped at or after this shows the bus passed the oldest SYNC waited for."""


class NoPassage:
    """A reader that sends no SYNC waits for none: its SYNCs come in the bus's order."""

    next_t = math.inf


class PatchAnswer:
    """One patch's answer in the open cycle: where each of its TPDOs goes in ``raw`` and its
    place in the answer, and what of it arrived."""

    def __init__(self, node_id: int, layouts: Sequence[TpdoLayout], *,
                 answer_order: str = "cob-id") -> None:
        self.node_id = node_id
        self.layouts = tuple(layouts)
        pdos = len(self.layouts)
        width = max([8, *(layout.size for layout in self.layouts)])
        self.stride = width + width % 2  # bytes per PDO in ``raw``: even, so that codes
        self.raw = bytearray(self.stride * pdos)  # read as UNSIGNED16 words
        self.zeros = bytes(self.stride * pdos)
        self.full = (1 << pdos) - 1
        self.seen = 0  # PDO bits received this cycle
        self.bad = 0  # PDO bits not trusted this cycle (duplicate, malformed)
        self.done = False  # handed on whole this cycle
        self.next = 0  # the place in the answer the next frame must take (0: not begun)
        self.ended = False  # the answer was broken: nothing more counts this cycle
        self.active = True  # False once replaced: frames held for it are judged late
        cob_ids = [layout.cob_id for layout in self.layouts]
        if answer_order == "cob-id":
            order = sorted(range(pdos), key=cob_ids.__getitem__)
        elif answer_order == "tpdo":
            order = list(range(pdos))
        else:
            raise ConfigError("answer_order", f"must be one of {', '.join(ANSWER_ORDERS)}, "
                              f"got {answer_order!r}")
        self.place = [0] * pdos  # PDO position in ``layouts`` -> its place in the answer
        for n, p in enumerate(order):
            self.place[p] = n
        self.offsets: dict[tuple[int, int], int] = {}
        """Each mapped object ``(index, subindex)`` -> its first byte in ``raw``."""
        for n, layout in enumerate(self.layouts):
            offset = self.stride * n
            for entry in layout.entries:
                self.offsets.setdefault((entry.index, entry.subindex), offset)
                offset += entry.bits // 8
        self.answered_bit = 0  # the PDO that carries 0x2006, the SYNC counter answered
        self.answered_at = 0  # its byte in that PDO
        if (ANSWERED, 0) in self.offsets:
            pdo, self.answered_at = divmod(self.offsets[(ANSWERED, 0)], self.stride)
            self.answered_bit = 1 << pdo

    def entries(self: Slot) -> dict[int, Entry[Slot]]:
        """COB-ID -> :data:`Entry` of each of the patch's TPDOs."""
        return {layout.cob_id: (self, 1 << p, self.stride * p, layout.size, self.place[p])
                for p, layout in enumerate(self.layouts)}

    @property
    def missing(self) -> int:
        """The PDO bits absent or not trusted in the open cycle."""
        return self.full & ~(self.seen & ~self.bad)

    def reset(self) -> None:
        self.seen = self.bad = self.next = 0
        self.done = self.ended = False
        self.raw[:] = self.zeros


class AnswerCycles(Generic[Slot]):
    """The open cycle and every patch's answer to it (module docstring).

    :meth:`take` judges a frame under ``_lock``; the owner holds the lock around all else
    (opening a cycle, changing the patches). Subclasses take the samples (:meth:`_sample`),
    the frames that are no patch's TPDO (:meth:`_other`), and may follow answers as they
    end (:meth:`_answer_over`) and the bus passing a SYNC (:meth:`_bus_passed`)."""

    def __init__(self, sync_window_s: float, stats: AnswerCounters) -> None:
        self.sync_window_s = sync_window_s
        self.stats = stats
        self._lock = threading.Lock()
        self._passage: Passage = NoPassage()
        self._table: dict[int, Entry[Slot]] = {}  # replaced, never mutated
        self._slots: dict[int, Slot] = {}  # node-ID -> its answer
        self._cycle: Cycle | None = None
        self._start, self._end = math.inf, -math.inf  # no cycle open
        self._held: list[tuple[Entry[Slot], bytes, float]] = []

    # -- frames -----------------------------------------------------------------------------

    def take(self, msg: can.Message) -> bool:
        """Judge ``msg`` if it is a TPDO of a patch's answer: its cycle's, held for the next
        cycle, or late; otherwise :meth:`_other` handles it (False by default)."""
        if msg.timestamp >= self._passage.next_t:
            self._bus_passed(msg.timestamp)
        entry = self._table.get(msg.arbitration_id)
        if entry is None or msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame:
            return self._other(msg)
        with self._lock:
            self.stats.frames_in += 1
            if self._start <= msg.timestamp <= self._end:
                self._accept(entry, msg.data)
            elif msg.timestamp > self._end and len(self._held) < 2 * len(self._table):
                self._held.append((entry, bytes(msg.data), msg.timestamp))
            else:
                self.stats.late_frames += 1
        return True

    def _accept(self, entry: Entry[Slot], data: bytes | bytearray) -> None:
        """One in-window frame: it extends the cycle's answer or is turned away."""
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
            self._answer_over(slot)
            slot.done = True
            self._sample(slot, self._cycle, 0, True)

    def _stale(self, slot: Slot, data: bytes | bytearray) -> bool:
        """The PDO names the SYNC it answers (0x2006), and it is not this cycle's: an answer
        to an earlier SYNC, counted ``stale_answers`` and ``late_frames``."""
        counter = self._cycle[1] if self._cycle is not None else 0
        if not counter or len(data) <= slot.answered_at or data[slot.answered_at] == counter:
            return False
        self.stats.stale_answers += 1
        self.stats.late_frames += 1
        return True

    def _turn_away(self, entry: Entry[Slot], data: bytes | bytearray) -> None:
        """A frame that does not extend the cycle's answer (module docstring)."""
        slot, bit, offset, size, place = entry
        stats = self.stats
        if not slot.next and not slot.ended:
            stats.late_frames += 1  # the tail of an earlier answer
        elif not slot.seen & bit:
            stats.out_of_order_frames += 1
            self._answer_over(slot)
            slot.ended = True
        else:
            stats.duplicate_frames += 1
            if slot.done and not place:
                stats.second_answers += 1
            # The frame just taken, again with the same bytes: a CAN receiver can get a
            # frame twice when its sender retransmits after an error in the last bit.
            repeat = place == slot.next - 1 and slot.raw[offset:offset + size] == data[:size]
            if not (repeat or slot.done or slot.ended):
                self._answer_over(slot)
                slot.bad |= bit
                slot.ended = True

    # -- cycles -----------------------------------------------------------------------------

    def _open(self, cycle: int, sync_counter: int, timestamp: float) -> None:
        """Close the open cycle, open ``cycle`` (its SYNC passed at ``timestamp``) and judge
        the frames held for it."""
        self._close()
        self._cycle = (cycle, sync_counter, timestamp)
        self._opened(cycle)
        self._start = timestamp
        self._end = timestamp + self.sync_window_s if self.sync_window_s else math.inf
        held, self._held = self._held, []
        for entry, data, t in held:
            if self._start <= t <= self._end:
                self._accept(entry, data)
            else:
                self.stats.late_frames += 1

    def _close(self) -> None:
        """Hand on the open cycle's unfinished answers as incomplete samples."""
        if self._cycle is not None:
            for slot in self._slots.values():
                if not slot.done:
                    self._sample(slot, self._cycle, slot.missing, False)
        for slot in self._slots.values():
            slot.reset()

    def _end_cycles(self) -> None:
        """Close the open cycle and open none (the bus or the recording ended)."""
        self._close()
        self._cycle = None
        self._start, self._end = math.inf, -math.inf

    # -- what subclasses do -----------------------------------------------------------------

    def _sample(self, slot: Slot, cycle: Cycle, missing: int, complete: bool) -> None:
        """``slot``'s sample of ``cycle``, the open cycle: ``slot.raw`` holds it, ``missing``
        the PDO bits absent or not trusted (its answer whole, at once; else when the cycle
        closes)."""
        raise NotImplementedError

    def _other(self, msg: can.Message) -> bool:
        """A frame that is no patch's TPDO (SYNC, heartbeat, ...); what :meth:`take` returns."""
        return False

    def _bus_passed(self, timestamp: float) -> None:
        """A frame stamped ``timestamp``, at or after ``_passage.next_t``, was taken."""

    def _answer_over(self, slot: Slot) -> None:
        """``slot``'s answer to the open cycle is whole or broken off, just now (before
        ``done`` or ``ended`` is set)."""

    def _opened(self, cycle: int) -> None:
        """Cycle ``cycle`` is open, before the frames held for it are judged."""
