"""Heartbeat producer: the NMT state on 0x700 + node-ID every 0x1017 milliseconds."""

from __future__ import annotations

from typing import Any

import can
import canopen

from canbus.echoes import EchoLedger, echo_ledger


class HeartbeatProducer:
    """A cyclic frame whose period follows object 0x1017 and whose byte follows the state.

    On a bus that echoes its own frames each heartbeat is noted in the bus's
    :class:`~canbus.echoes.EchoLedger` just before it is sent, so a master auditing the
    node's ID tells its echoes from another node's heartbeats."""

    def __init__(self, node_id: int) -> None:
        self.cob_id = 0x700 + node_id
        self.period_ms = 0
        self._state = 0
        self._task: Any = None
        self._network: canopen.Network | None = None
        self._ledger: EchoLedger | None = None  # set while the heartbeats are noted

    def start(self, network: canopen.Network, period_ms: int, state: int) -> None:
        """(Re)start with ``period_ms``; 0 disables the heartbeat."""
        self.stop()
        self._network = network
        self.period_ms = period_ms
        self._state = state
        if period_ms > 0:
            self._task = self._send_periodic(network, period_ms / 1000.0)

    def _send_periodic(self, network: canopen.Network, period_s: float) -> Any:
        bus = network.bus
        if bus is None or not echo_ledger(bus).echoes:  # canopen's task (socketcan: the kernel's)
            self._ledger = None
            return network.send_periodic(self.cob_id, bytes([self._state]), period_s)
        self._ledger = echo_ledger(bus)
        msg = can.Message(arbitration_id=self.cob_id, data=bytes([self._state]),
                          is_extended_id=False)
        return bus.send_periodic(msg, period_s, modifier_callback=self._stamp)

    def _stamp(self, msg: can.Message) -> None:
        """Just before each send, on the task's thread: the state now, noted as sent."""
        msg.data = bytearray([self._state])
        if self._ledger is not None:
            self._ledger.sending(self.cob_id, msg.data)

    def set_period(self, period_ms: int) -> None:
        if self._network is not None:
            self.start(self._network, period_ms, self._state)

    def set_state(self, state: int) -> None:
        self._state = state
        if self._task is not None and self._ledger is None:  # a stamped task reads it
            self._task.update(bytes([state]))

    def stop(self) -> None:
        if self._task is not None:
            self._task.stop()
            self._task = None
