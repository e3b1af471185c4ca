"""A patch's EMCYs: consumed with bounded memory, logged without flooding.

canopen's ``EmcyConsumer`` keeps every EMCY in ``log`` and every active one in ``active``
(until an error reset) for as long as the process runs: a taxel fault never reset, sent
3,000 times a second, grows the host by about 0.4 KiB an EMCY. :class:`BoundedEmcyConsumer`
keeps the newest :data:`EMCY_LOG_KEPT` of each (trimmed once a list holds twice as many),
takes a short or long frame (not 8 bytes, as CiA 301 has them) as what it carries, padded
or cut, and counts everything. :class:`EmcyLog` writes the log lines, a few per patch and
error every 10 s at most.
"""

from __future__ import annotations

import logging
from types import MappingProxyType

from canopen.emcy import EMCY_STRUCT, EmcyConsumer, EmcyError

from canbus.ratelog import RateLimitedLog
from skin.constants import TAXELS_PER_PATCH

logger = logging.getLogger(__name__)

EMCY_LOG_KEPT = 256
"""EMCYs kept in ``log`` and in ``active`` (each trimmed to this many once it holds twice
as many)."""
DEVICE_HARDWARE, ERROR_RESET = 0x5000, 0x0000
EMCY_TEXT = MappingProxyType({DEVICE_HARDWARE: "taxel fault (device hardware)",
                              ERROR_RESET: "taxel recovered"})
TAXEL_FAULTS = MappingProxyType({1: "open", 2: "short", 3: "saturated"})  # 0x2004, per pillar


class BoundedEmcyConsumer(EmcyConsumer):
    """canopen's EMCY consumer with bounded ``log`` and ``active`` lists (module docstring)."""

    def __init__(self) -> None:
        super().__init__()  # type: ignore[no-untyped-call]
        self.received = 0
        self.malformed = 0  # frames not 8 bytes long (taken padded or cut)

    def on_emcy(self, can_id: int, data: bytes | bytearray, timestamp: float) -> None:
        self.received += 1
        if len(data) != EMCY_STRUCT.size:
            self.malformed += 1
            data = bytes(data[:EMCY_STRUCT.size]).ljust(EMCY_STRUCT.size, b"\x00")
        code, register, payload = EMCY_STRUCT.unpack(data)
        entry = EmcyError(code, register, payload, timestamp)
        with self.emcy_received:
            if code & 0xFF00 == 0:  # error reset
                self.active = []
            else:
                self.active.append(entry)
                _trim(self.active)
            self.log.append(entry)
            _trim(self.log)
            self.emcy_received.notify_all()
        for callback in self.callbacks:
            callback(entry)


def _trim(entries: list[EmcyError]) -> None:
    if len(entries) > 2 * EMCY_LOG_KEPT:
        del entries[:-EMCY_LOG_KEPT]


class EmcyLog:
    """Log lines for EMCYs: at most 3 per patch, code and taxel every 10 s, then a count."""

    def __init__(self) -> None:
        self._log = RateLimitedLog(logger)

    def note(self, node_id: int, entry: EmcyError) -> None:
        text = EMCY_TEXT.get(entry.code, entry.get_desc() or "error")
        data = bytes(entry.data)
        key = (node_id, entry.code, data[0] if data else None)
        if entry.code == DEVICE_HARDWARE and len(data) >= 2:
            status = data[1]
            pillars = ", ".join(f"{axis} {TAXEL_FAULTS[status >> (2 * k) & 3]}"
                                for k, axis in enumerate("zxy") if status >> (2 * k) & 3)
            self._log.log(logging.WARNING, key, "patch %d: EMCY 0x%04X %s: taxel %d (%s); "
                          "masked", node_id, entry.code, text, data[0], pillars or "status 0")
        elif entry.code == ERROR_RESET and data:
            self._log.log(logging.INFO, key, "patch %d: EMCY 0x%04X %s: taxel %d", node_id,
                          entry.code, text, data[0])
        else:
            self._log.log(logging.WARNING, key, "patch %d: EMCY 0x%04X %s (register 0x%02X, "
                          "data %s)", node_id, entry.code, text, entry.register, data.hex())

    def flush(self) -> None:
        self._log.flush()


def taxel_of(entry: EmcyError) -> int | None:
    """The taxel a patch's taxel EMCY (fault or recovery) names; None for any other."""
    data = bytes(entry.data)
    if entry.code not in (DEVICE_HARDWARE, ERROR_RESET) or not data:
        return None
    return data[0] if data[0] < TAXELS_PER_PATCH else None
