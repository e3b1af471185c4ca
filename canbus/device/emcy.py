"""EMCY producer for pillar faults: one message when a taxel faults, one when it recovers.

Error code 0x5000 (device hardware) when a taxel's status becomes non-zero, 0x0000
(error reset) when it returns to zero; 0x6100 (internal software) once, when the patch can
no longer take samples (:meth:`FaultReporter.halt`: it answers no SYNC from then on).
The error register (0x1001) has bit 0 (generic) and bit 7 (manufacturer-specific) set
while any taxel is faulty or the patch is halted. The five manufacturer bytes are the
taxel number and its status byte (see ``canbus.codes``).
"""

from __future__ import annotations

import struct

import canopen
import numpy as np
from numpy.typing import NDArray

from canbus.device.error_history import ErrorHistory

DEVICE_HARDWARE = 0x5000
INTERNAL_SOFTWARE = 0x6100
ERROR_RESET = 0x0000
REGISTER_FAULT = 0x81
_EMCY = struct.Struct("<HBBB3x")


class FaultReporter:
    """Compares each new taxel status with the last and reports the changes."""

    def __init__(self) -> None:
        self.status = np.zeros(9, dtype=np.uint8)
        self.halted = False
        """The patch takes no more samples (:meth:`halt`)."""

    @property
    def error_register(self) -> int:
        return REGISTER_FAULT if self.halted or self.status.any() else 0

    def halt(self, network: canopen.Network | None, cob_id: int,
             history: ErrorHistory | None = None) -> None:
        """The patch can no longer take samples: keep it in ``history`` and send one EMCY
        0x6100 if ``network`` is given (once: a halted patch stays halted)."""
        if self.halted:
            return
        self.halted = True
        if history is not None:
            history.push(INTERNAL_SOFTWARE)
        if network is None or cob_id & 0x8000_0000:
            return
        network.send_message(cob_id & 0x7FF, _EMCY.pack(INTERNAL_SOFTWARE,
                                                        self.error_register, 0, 0))

    def update(self, status: NDArray[np.uint8], network: canopen.Network | None,
               cob_id: int, history: ErrorHistory | None = None) -> None:
        """Adopt ``status``; send EMCY for every taxel that changed if ``network`` is given;
        keep each new fault in ``history`` (0x1003)."""
        changed = np.flatnonzero(status != self.status)
        self.status = status.copy()
        if history is not None:
            for taxel in changed.tolist():
                if status[taxel]:
                    history.push(DEVICE_HARDWARE, taxel | (int(status[taxel]) << 8))
        if network is None or cob_id & 0x8000_0000:
            return
        for taxel in changed.tolist():
            code = DEVICE_HARDWARE if status[taxel] else ERROR_RESET
            payload = _EMCY.pack(code, self.error_register, taxel, int(status[taxel]))
            network.send_message(cob_id & 0x7FF, payload)
