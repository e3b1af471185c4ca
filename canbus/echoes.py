"""Which frames on an audited COB-ID are the echoes of this process's own sends, and which
another node sent: by the frames this process sent there, never by when they were sent.

On a bus that hands a process its own frames back (udp_multicast, ``canbus.rxfilter``) a
frame on a COB-ID this process sends on may be its own echo or another node's. Where the
process must hear another sender (a second node at its force node's ID), it audits that
COB-ID (:meth:`EchoLedger.audit`) instead of claiming it: its senders note each frame just
before sending it (:meth:`EchoLedger.sending`), and each frame received there takes away
one noted frame with the same data (:meth:`EchoLedger.is_echo`). An echo always finds its
noted frame, however sends, echoes and other nodes' frames interleave; a frame no noted
frame is left for is another node's. So every frame more than this process sent is found
(the same bytes included: a second heartbeat ``05`` a period), but the one frame that
stands in for an echo the socket lost (a full receive buffer), within
:data:`ECHO_WAIT_S`, is not.

On a bus that does not echo nothing is noted: every frame received is another node's.
"""

from __future__ import annotations

import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable

from canbus.perbus import PerBus
from canbus.rxfilter import echoes_own_frames

ECHO_WAIT_S = 10.0
"""How long a noted frame waits for its echo: one not back by then was lost."""


class EchoLedger:
    """The frames this process sent on the audited COB-IDs of one bus, until their echoes
    come back."""

    def __init__(self, echoes: bool, clock: Callable[[], float] = time.monotonic) -> None:
        self.echoes = echoes
        """The bus hands this process its own frames back: only then is anything noted."""
        self._clock = clock
        self._audits: Counter[int] = Counter()
        self._sent: dict[int, deque[tuple[bytes, float]]] = {}
        self._lock = threading.Lock()

    def audit(self, cob_ids: Iterable[int]) -> None:
        """Note the frames sent on ``cob_ids`` from now on (once more for each caller)."""
        with self._lock:
            self._audits.update(cob_ids)

    def forget(self, cob_ids: Iterable[int]) -> None:
        """Undo one :meth:`audit` of ``cob_ids``; the last one drops what was noted."""
        with self._lock:
            for cob_id in cob_ids:
                self._audits[cob_id] -= 1
                if self._audits[cob_id] <= 0:
                    del self._audits[cob_id]
                    self._sent.pop(cob_id, None)

    def sending(self, cob_id: int, data: bytes | bytearray) -> None:
        """This process is about to send ``data`` on ``cob_id`` (call it before the send:
        the echo may come back before the send returns)."""
        if not self.echoes:
            return
        with self._lock:
            if cob_id not in self._audits:
                return
            sent = self._sent.setdefault(cob_id, deque())
            now = self._clock()
            _drop_lost(sent, now)
            sent.append((bytes(data), now))

    def is_echo(self, cob_id: int, data: bytes | bytearray) -> bool:
        """Whether a frame received on ``cob_id`` is the echo of one this process sent
        (it then stands for that one: the next frame with the same data needs another)."""
        with self._lock:
            sent = self._sent.get(cob_id)
            if not sent:
                return False
            _drop_lost(sent, self._clock())
            for at, (noted, _) in enumerate(sent):
                if noted == data:
                    del sent[at]
                    return True
            return False


def _drop_lost(sent: deque[tuple[bytes, float]], now: float) -> None:
    while sent and now - sent[0][1] > ECHO_WAIT_S:
        sent.popleft()


echo_ledger = PerBus(lambda bus: EchoLedger(echoes_own_frames(bus)))
"""``echo_ledger(bus)``: the one :class:`EchoLedger` of ``bus`` (its senders and its
listeners share it)."""
