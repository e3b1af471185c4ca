"""NMT slave: the CiA 301 state machine of one node, driven by frames on COB-ID 0x000."""

from __future__ import annotations

import logging
from collections.abc import Callable

import canopen

from canbus.echoes import echo_ledger

logger = logging.getLogger(__name__)

INITIALISING, STOPPED, OPERATIONAL, PRE_OPERATIONAL = 0, 4, 5, 127
START, STOP, ENTER_PRE_OPERATIONAL, RESET_NODE, RESET_COMMUNICATION = 1, 2, 0x80, 0x81, 0x82
_TARGET = {START: OPERATIONAL, STOP: STOPPED, ENTER_PRE_OPERATIONAL: PRE_OPERATIONAL}


class NmtSlave:
    """States INITIALISING -> PRE-OPERATIONAL <-> OPERATIONAL <-> STOPPED, and the resets.

    ``on_reset(application)`` restores object values (the whole dictionary when
    ``application`` is true, the communication area otherwise) before the new boot-up;
    ``on_state(state)`` follows every state change.
    """

    def __init__(self, node_id: int, *, on_reset: Callable[[bool], None],
                 on_state: Callable[[int], None]) -> None:
        self.node_id = node_id
        self.state = INITIALISING
        self.network: canopen.Network | None = None
        self._on_reset = on_reset
        self._on_state = on_state

    def boot(self, network: canopen.Network) -> None:
        """Finish initialisation: send the boot-up message and enter PRE-OPERATIONAL."""
        self.network = network
        cob_id, bootup = 0x700 + self.node_id, b"\x00"
        if network.bus is not None:
            echo_ledger(network.bus).sending(cob_id, bootup)
        network.send_message(cob_id, bootup)
        self._set(PRE_OPERATIONAL)

    def on_command(self, can_id: int, data: bytearray | bytes, timestamp: float) -> None:
        """Handle one NMT frame; CiA 301 NMT frames have exactly 2 bytes, others are ignored."""
        if len(data) != 2 or data[1] not in (0, self.node_id) or self.network is None:
            return
        command = data[0]
        if command in _TARGET:
            self._set(_TARGET[command])
        elif command in (RESET_NODE, RESET_COMMUNICATION):
            self._set(INITIALISING)
            self._on_reset(command == RESET_NODE)
            self.boot(self.network)
        else:
            logger.info("node %d ignored NMT command 0x%02X", self.node_id, command)

    def enter(self, state: int) -> None:
        """Change state as the device itself decides (an error behaviour, CiA 301 0x1029)."""
        if self.network is not None:
            self._set(state)

    def _set(self, state: int) -> None:
        if state != self.state:
            self.state = state
            self._on_state(state)
