"""Heartbeat producer: the NMT state on 0x700 + node-ID every 0x1017 milliseconds."""

from __future__ import annotations

from typing import Any

import canopen


class HeartbeatProducer:
    """A cyclic frame whose period follows object 0x1017 and whose byte follows the state."""

    def __init__(self, node_id: int) -> None:
        self.cob_id = 0x700 + node_id
        self.period_ms = 0
        self._state = 0
        self._task: Any = None
        self._network: canopen.Network | None = None

    def start(self, network: canopen.Network, period_ms: int, state: int) -> None:
        """(Re)start with ``period_ms``; 0 disables the heartbeat."""
        self.stop()
        self._network = network
        self.period_ms = period_ms
        self._state = state
        if period_ms > 0:
            self._task = network.send_periodic(self.cob_id, bytes([state]), period_ms / 1000.0)

    def set_period(self, period_ms: int) -> None:
        if self._network is not None:
            self.start(self._network, period_ms, self._state)

    def set_state(self, state: int) -> None:
        self._state = state
        if self._task is not None:
            self._task.update(bytes([state]))

    def stop(self) -> None:
        if self._task is not None:
            self._task.stop()
            self._task = None
