"""Patch answers off a bus or a recording, judged as the host judges them.

:class:`AnswerReader` is what a listen-only host's data plane does with the patches' PDOs,
without decoding them: it takes the frames in the bus's order (a ``can.Listener``), opens
a cycle at every SYNC (numbered 1, 2, ... as the listen-only host numbers them; a SYNC
with more than one data byte, a remote or an extended frame at 0x080 is none) and judges
each patch's TPDOs by :mod:`canbus.answers`, with no SYNC window: a cycle lasts until
the next SYNC, as a listen-only host and ``skin decode`` take it (a recording keeps the
order of the frames, not the time a live receiver took them). Every patch it follows
gets one :class:`Answer` per cycle, complete or not; :meth:`end` closes the last one.

Which patches: :meth:`follow`, from the next SYNC on. A reader that learns of a patch (a
config, an SDO transfer, its defaults seen) in the middle of a cycle missed the frames of
that cycle it could not yet call the patch's: it judges the patch from the next cycle on.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import can

from canbus.answers import AnswerCycles, Cycle, PatchAnswer, counter_of_sync


@dataclass
class AnswerStats:
    """What became of the patches' frames (:mod:`canbus.answers`)."""

    frames_in: int = 0  # TPDO frames of the patches followed
    late_frames: int = 0
    duplicate_frames: int = 0
    out_of_order_frames: int = 0
    second_answers: int = 0
    stale_answers: int = 0
    malformed_frames: int = 0


@dataclass(frozen=True)
class Answer:
    """One patch's sample of one SYNC cycle."""

    node_id: int
    cycle: int  # 1 for the first SYNC the reader saw (or after ``cycles``), 2, ...
    sync_counter: int  # the SYNC's counter byte, 0 without one
    sync_time: float  # the SYNC's timestamp
    complete: bool  # every TPDO of one answer, once, in order, in the cycle
    missing: int  # bit p: PDO p (``PatchAnswer.layouts`` order) absent or not trusted
    payload: bytes  # PDO p's bytes at ``stride * p`` (:attr:`PatchAnswer.raw`)


class AnswerReader(AnswerCycles[PatchAnswer], can.Listener):
    """Each followed patch's :class:`Answer` of each SYNC cycle, to ``on_answer`` (on the
    thread that hands it the frames). ``cycles``: SYNCs before the first one it is given
    (a reader started in the middle of a recording numbers its cycles as one started at
    its beginning)."""

    stats: AnswerStats

    def __init__(self, on_answer: Callable[[Answer], None], *, cycles: int = 0) -> None:
        super().__init__(0.0, AnswerStats())
        self.on_answer = on_answer
        self.cycles = cycles
        self._following: dict[int, PatchAnswer] | None = None

    def follow(self, patches: Iterable[PatchAnswer]) -> None:
        """Judge the answers of ``patches`` (and no other) from the next SYNC on."""
        with self._lock:
            self._following = {patch.node_id: patch for patch in patches}

    def on_message_received(self, msg: can.Message) -> None:
        self.take(msg)

    def _other(self, msg: can.Message) -> bool:
        counter = counter_of_sync(msg)
        if counter is not None:
            self.sync(counter, msg.timestamp)
        return False

    def sync(self, counter: int, timestamp: float) -> None:
        """A SYNC with ``counter`` (0 without one) at ``timestamp``: the open cycle closes,
        the next one opens."""
        with self._lock:
            self.cycles += 1
            self._open(self.cycles, counter, timestamp)

    def end(self) -> None:
        """The bus or the recording ended: the open cycle closes."""
        with self._lock:
            self._end_cycles()

    def _opened(self, cycle: int) -> None:
        following, self._following = self._following, None
        if following is not None:
            for old in self._slots.values():
                old.active = False  # frames held for it are not the new one's
            self._slots = following
            table = {}
            for patch in following.values():
                patch.active = True
                patch.reset()
                table.update(patch.entries())
            self._table = table

    def _sample(self, slot: PatchAnswer, cycle: Cycle, missing: int, complete: bool) -> None:
        self.on_answer(Answer(slot.node_id, cycle[0], cycle[1], cycle[2], complete, missing,
                              bytes(slot.raw)))
