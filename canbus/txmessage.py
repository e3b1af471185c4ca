"""The ``can.Message`` this package sends: the same frame, a cheaper deep copy.

A python-can virtual bus hands each receiver ``copy.deepcopy`` of every frame sent.
``Message.__deepcopy__`` deep-copies the payload ``bytearray`` through the generic
``copy`` machinery (``__reduce_ex__``), about 3 µs of a 4 µs copy; with 112 TPDOs per
10 ms cycle in ``skin demo`` that was a third of a millisecond on the latency path.
:class:`TxMessage` copies the payload with ``bytearray(data)`` instead and returns a
plain ``can.Message``, equal field for field, sharing nothing mutable with the
original. Other interfaces do not copy and see an ordinary message.
"""

from __future__ import annotations

from copy import deepcopy
from typing import Any

import can


class TxMessage(can.Message):
    """A ``can.Message`` whose ``copy.deepcopy`` is a plain, independent ``can.Message``."""

    __slots__ = ()

    def __deepcopy__(self, memo: dict[int, Any] | None) -> can.Message:
        channel = self.channel
        if not (channel is None or isinstance(channel, int | str)):
            channel = deepcopy(channel, memo)  # a sequence of ints
        return can.Message(
            timestamp=self.timestamp,
            arbitration_id=self.arbitration_id,
            is_extended_id=self.is_extended_id,
            is_remote_frame=self.is_remote_frame,
            is_error_frame=self.is_error_frame,
            channel=channel,
            dlc=self.dlc,
            data=bytearray(self.data),
            is_fd=self.is_fd,
            is_rx=self.is_rx,
            bitrate_switch=self.bitrate_switch,
            error_state_indicator=self.error_state_indicator,
        )
