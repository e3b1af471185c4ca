"""One patch's answers to SYNC as samples of a PDO reader (:mod:`canbus.tools.pdo_samples`),
joined by the host's rule.

:class:`PatchAnswers` is a :class:`~canbus.tools.pdo_assembly.PdoAssembly` (the mapping,
and how a sample's variables are read) whose samples are the patch's answers as
:mod:`canbus.answers` judges them (through a one-patch
:class:`~canbus.tools.answer_reader.AnswerReader`): one per SYNC cycle from the first SYNC
after it was made, complete or not, stamped with its SYNC's time, closed by the next
SYNC (or :meth:`finish`), never by a time.
"""

from __future__ import annotations

from collections.abc import Sequence

import can
import canopen

from canbus.answers import PatchAnswer
from canbus.pdo_codec import TpdoLayout
from canbus.tools.answer_reader import Answer, AnswerReader
from canbus.tools.pdo_assembly import JoinedPdos, PdoAssembly


class PatchAnswers(PdoAssembly):
    """Patch ``node_id``'s answers (module docstring); ``cycles``: the SYNCs seen before
    it was made, so that its cycles are numbered as the reader's."""

    def __init__(self, node_id: int, layouts: Sequence[TpdoLayout],
                 od: canopen.ObjectDictionary, *, order: str = "cob-id",
                 cycles: int = 0) -> None:
        super().__init__(node_id, layouts, od, order=order)
        self._answers: list[Answer] = []
        self._reader = AnswerReader(self._answers.append, cycles=cycles)
        self._answer = PatchAnswer(node_id, self.layouts, answer_order=order)
        self._reader.follow([self._answer])

    def take(self, cob_id: int, data: bytes, timestamp: float,
             period_s: float) -> list[JoinedPdos]:
        """One frame of PDO ``cob_id``: the answer it completes, if any."""
        self._reader.take(can.Message(timestamp=timestamp, arbitration_id=cob_id, data=data,
                                      is_extended_id=False, check=False))
        self.malformed = self._reader.stats.malformed_frames
        return self._samples()

    def sync(self, counter: int, timestamp: float) -> list[JoinedPdos]:
        """A SYNC: the open cycle's answer, if it was not complete, and a new cycle."""
        self._reader.sync(counter, timestamp)
        return self._samples()

    def expire(self, now: float, period_s: float) -> JoinedPdos | None:
        return None  # a cycle lasts until the next SYNC

    def finish(self) -> list[JoinedPdos]:
        """The bus or the recording ended: the open cycle's answer, if it was not complete."""
        self._reader.end()
        return self._samples()

    def _samples(self) -> list[JoinedPdos]:
        answers, self._answers[:] = list(self._answers), []
        return [self._sample(a) for a in answers]

    def _sample(self, answer: Answer) -> JoinedPdos:
        """The answer in the assembly's buffer layout (:meth:`PdoAssembly.values` reads it)."""
        buffer = bytearray(self.size)
        stride = self._answer.stride
        for bit, offset, size in self.slots.values():
            buffer[offset:offset + size] = answer.payload[stride * bit:stride * bit + size]
        arrived = self.full & ~answer.missing
        return JoinedPdos(self.node_id, answer.sync_time, bytes(buffer), arrived,
                         answer.complete, answer.cycle)
