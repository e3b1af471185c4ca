"""The notifier's one listener in front of a data plane."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import can

if TYPE_CHECKING:
    from canbus.master.dataplane import DataPlane


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
