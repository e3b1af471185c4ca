# canopen 2.4 ships py.typed but leaves LocalNode/SdoServer methods unannotated.
# mypy: disable-error-code="no-untyped-call"
"""0x1003 pre-defined error field: the errors behind each EMCY, newest first (CiA 301).

Each entry is an UNSIGNED32: the EMCY error code in bits 0..15, manufacturer-specific
information in bits 16..31 (here the taxel and its status byte, as the EMCY's bytes 3..4).
Sub-index 0 counts the entries; writing 0 to it clears the history, any other value aborts
with 0x06090030; reading an entry beyond the count aborts with 0x08000024 (no data).
An error reset (EMCY code 0x0000) is not an error and adds no entry.
"""

from __future__ import annotations

import threading
from typing import Any

from canopen.sdo.exceptions import SdoAbortedError

from canbus.device.object_store import ObjectStore

ERROR_FIELD = 0x1003
INVALID_VALUE = 0x0609_0030
NO_DATA = 0x0800_0024


class ErrorHistory:
    """The error field of one device; :meth:`push` from the EMCY producer."""

    def __init__(self, depth: int) -> None:
        self.depth = depth
        self.entries: list[int] = []  # newest first
        self._lock = threading.Lock()

    def attach(self, store: ObjectStore) -> None:
        if ERROR_FIELD not in store.object_dictionary:
            return
        store.validators.append(self._validate)
        store.add_write_callback(self._written)
        store.add_read_callback(self._read)

    def push(self, code: int, info: int = 0) -> None:
        with self._lock:
            self.entries.insert(0, (code & 0xFFFF) | ((info & 0xFFFF) << 16))
            del self.entries[self.depth:]

    def clear(self) -> None:
        with self._lock:
            self.entries.clear()

    def _validate(self, index: int, subindex: int, value: Any) -> None:
        if index == ERROR_FIELD and subindex == 0 and value != 0:
            raise SdoAbortedError(INVALID_VALUE)

    def _written(self, index: int, subindex: int, **_: Any) -> None:
        if index == ERROR_FIELD and subindex == 0:
            self.clear()

    def _read(self, index: int, subindex: int, **_: Any) -> int | None:
        if index != ERROR_FIELD:
            return None
        with self._lock:
            if subindex == 0:
                return len(self.entries)
            if subindex > len(self.entries):
                raise SdoAbortedError(NO_DATA)
            return self.entries[subindex - 1]
