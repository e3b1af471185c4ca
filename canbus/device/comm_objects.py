"""The communication objects a SYNC consumer checks and follows (CiA 301).

* 0x1005 COB-ID SYNC (rw): bits 0..10 the SYNC's CAN-ID, which the node consumes from
  then on; bit 30 (the node would generate SYNC) and bit 29 (a 29-bit ID) abort with
  0x06090030;
* 0x1019 synchronous counter overflow value (rw): 0 (the SYNC carries no counter) or
  2..240; 1 and 241..255 abort with 0x06090030. The node answers a SYNC with or without a
  counter byte either way (the host's CAN FD answer tells the cycle by it);
* 0x1029 error behaviour, sub 1 communication error (rw, 0..2): what the node does when it
  cannot send (bus-off, a send that fails): 0 enters PRE-OPERATIONAL if it was OPERATIONAL,
  1 stays, 2 enters STOPPED (:func:`communication_error_state`).
"""

from __future__ import annotations

from typing import Any

from canopen.sdo.exceptions import SdoAbortedError

from canbus.device.nmt_slave import OPERATIONAL, PRE_OPERATIONAL, STOPPED

COB_ID_SYNC, SYNC_OVERFLOW, ERROR_BEHAVIOUR = 0x1005, 0x1019, 0x1029
INVALID_VALUE = 0x0609_0030
GENERATES, EXTENDED = 1 << 30, 1 << 29


def validate(index: int, subindex: int, value: Any) -> None:
    """Refuse what a SYNC consumer cannot be told (an ObjectStore validator)."""
    if index == COB_ID_SYNC and int(value) & (GENERATES | EXTENDED):
        raise SdoAbortedError(INVALID_VALUE)
    if index == SYNC_OVERFLOW and (int(value) == 1 or int(value) > 240):
        raise SdoAbortedError(INVALID_VALUE)


def communication_error_state(behaviour: int, state: int) -> int:
    """The NMT state after a communication error, by 0x1029 sub 1."""
    if behaviour == 0 and state == OPERATIONAL:
        return PRE_OPERATIONAL
    if behaviour == 2:
        return STOPPED
    return state
