# canopen 2.4 ships py.typed but leaves LocalNode/SdoServer methods unannotated.
# mypy: disable-error-code="no-untyped-call"
"""TPDO service: CiA 301 rules for PDO parameters, and which PDOs fire when.

Transmission types: 1..240 send on every n-th SYNC; 0 sends on SYNC when the payload
changed; 254/255 are event-driven: sent when the event timer (ms) elapses, or, with
no event timer, when the payload changes, never faster than the inhibit time. Types
241..253 (reserved, RTR-only) are refused with 0x06090030.

Mapping changes follow CiA 301: invalidate the PDO (COB-ID bit 31), write sub-index 0
= 0, write the entries, write sub-index 0 = count, validate the PDO again.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from typing import Any

import numpy as np
from canopen.objectdictionary import ODVariable
from canopen.sdo.exceptions import SdoAbortedError

from canbus.device.object_store import ObjectStore
from canbus.pdo_codec import (
    COB_ID_INVALID,
    TPDO_COMM,
    TPDO_MAP,
    MappedEntry,
    PdoCodec,
    TpdoLayout,
    read_layouts,
)

UNSUPPORTED_ACCESS = 0x0601_0000
NOT_MAPPABLE = 0x0604_0041
EXCEEDS_PDO = 0x0604_0042
INVALID_VALUE = 0x0609_0030
EVENT_DRIVEN = (254, 255)
_DUE_S = 1e-9  # a clock read exactly at a period's end is due, whatever float rounding says


class TpdoTable:
    """The TPDOs of one node: parameter checks, the current codec and the schedule."""

    def __init__(self, store: ObjectStore, count: int) -> None:
        self.store = store
        self.count = count
        self.max_bytes = 8
        """The longest PDO the node sends: 8 on a classic bus, 64 on a CAN FD bus (CiA 1301:
        up to 64 mapped bytes, in one CAN FD frame)."""
        self._built: tuple[PdoCodec, list[tuple[int, int, int]]] | None = None
        self._build_lock = threading.Lock()
        self._last_sent: dict[int, float] = {}
        self._last_payload: dict[int, bytes] = {}
        store.validators.append(self.validate)
        store.add_write_callback(self._invalidate)

    @property
    def codec(self) -> PdoCodec:
        """The codec of the current mapping, built on first use after a change."""
        return self._current()[0]

    @property
    def _params(self) -> list[tuple[int, int, int]]:
        """(transmission type, inhibit time, event timer) of each valid PDO."""
        return self._current()[1]

    def _current(self) -> tuple[PdoCodec, list[tuple[int, int, int]]]:
        built = self._built
        if built is not None:
            return built
        # Built under the lock that invalidation takes: a write that lands while another
        # thread (a patch server's sample thread) reads the mapping invalidates after the
        # build, never before it, so no codec of a half-written mapping outlives the write.
        with self._build_lock:
            if self._built is None:
                value = self.store.value
                layouts = read_layouts(lambda i, s: int(value(i, s)), self.count)
                self._built = (PdoCodec(layouts, self.store.object_dictionary),
                               [(int(value(TPDO_COMM + lay.number - 1, 2)),
                                 int(value(TPDO_COMM + lay.number - 1, 3)),
                                 int(value(TPDO_COMM + lay.number - 1, 5))) for lay in layouts])
            return self._built

    @property
    def transmission_types(self) -> tuple[int, ...]:
        """The transmission type of each valid PDO, in ``codec.layouts`` order."""
        return self.mapping()[1]

    def mapping(self) -> tuple[PdoCodec, tuple[int, ...]]:
        """The codec and the transmission types of one and the same mapping."""
        codec, params = self._current()
        return codec, tuple(trans for trans, _, _ in params)

    def reset(self) -> None:
        with self._build_lock:
            self._built = None
        self._last_sent.clear()
        self._last_payload.clear()

    def _invalidate(self, index: int, **_: Any) -> None:
        if TPDO_COMM <= index < TPDO_COMM + self.count or TPDO_MAP <= index < TPDO_MAP + self.count:
            with self._build_lock:
                self._built = None

    def due_on_sync(self, counter: int, payloads: Sequence[bytes]) -> list[int]:
        """Positions (in ``codec.layouts``) of the PDOs that SYNC number ``counter`` sends;
        ``payloads``: each PDO's bytes, for type 0 (sent when they changed)."""
        due = []
        for p, (trans, _, _) in enumerate(self._params):
            cyclic = 1 <= trans <= 240 and counter % trans == 0
            if cyclic or (trans == 0 and self._changed(p, payloads[p])):
                due.append(p)
        return due

    def due_on_event(self, now: float, payloads: Sequence[bytes]) -> list[int]:
        """Positions of the event-driven PDOs due at ``now`` (seconds, monotonic)."""
        due = []
        for p, (trans, inhibit_100us, timer_ms) in enumerate(self._params):
            if trans not in EVENT_DRIVEN:
                continue
            last = self._last_sent.get(p, -np.inf)
            if timer_ms:
                fire = now - last >= timer_ms / 1000.0 - _DUE_S
            else:
                fire = (now - last >= inhibit_100us / 10_000.0 - _DUE_S
                        and self._changed(p, payloads[p]))
            if fire:
                due.append(p)
        for p in due:
            self._last_sent[p] = now
        return due

    def _changed(self, p: int, payload: bytes) -> bool:
        if self._last_payload.get(p) == payload:
            return False
        self._last_payload[p] = payload
        return True

    def validate(self, index: int, subindex: int, value: Any) -> None:
        """Refuse writes that CiA 301 forbids (runs before the value is stored)."""
        if TPDO_COMM <= index < TPDO_COMM + self.count:
            self._validate_comm(index - TPDO_COMM, subindex, int(value))
        elif TPDO_MAP <= index < TPDO_MAP + self.count:
            self._validate_mapping(index - TPDO_MAP, subindex, int(value))

    def _valid(self, n: int) -> bool:
        return not int(self.store.value(TPDO_COMM + n, 1)) & COB_ID_INVALID

    def _validate_comm(self, n: int, subindex: int, value: int) -> None:
        if subindex == 1:
            old = int(self.store.value(TPDO_COMM + n, 1))
            if value & 0x2000_0000 or value & 0x1FFF_F800:
                raise SdoAbortedError(INVALID_VALUE)  # 29-bit identifiers are not supported
            both_valid = not (old | value) & COB_ID_INVALID
            if both_valid and (old ^ value) & 0x7FF:
                raise SdoAbortedError(INVALID_VALUE)
        bad_type = subindex == 2 and not (value <= 240 or value in EVENT_DRIVEN)
        if bad_type or (subindex == 3 and self._valid(n)):
            raise SdoAbortedError(INVALID_VALUE)

    def _validate_mapping(self, n: int, subindex: int, value: int) -> None:
        if self._valid(n):
            raise SdoAbortedError(UNSUPPORTED_ACCESS)
        if subindex == 0:
            entries = [MappedEntry.from_raw(int(self.store.value(TPDO_MAP + n, s)))
                       for s in range(1, value + 1)]
            for entry in entries:
                self._check_entry(entry)
            if sum(e.bits for e in entries) > 8 * self.max_bytes:
                raise SdoAbortedError(EXCEEDS_PDO)
        elif int(self.store.value(TPDO_MAP + n, 0)) != 0:
            raise SdoAbortedError(UNSUPPORTED_ACCESS)
        else:
            self._check_entry(MappedEntry.from_raw(value))

    def _check_entry(self, entry: MappedEntry) -> None:
        od = self.store.object_dictionary
        try:
            obj = od[entry.index]
            if isinstance(obj, ODVariable):
                var = obj
            elif entry.subindex in obj.subindices:
                var = obj.subindices[entry.subindex]
            else:
                raise SdoAbortedError(NOT_MAPPABLE)
        except KeyError as err:
            raise SdoAbortedError(NOT_MAPPABLE) from err
        if not var.pdo_mappable or len(var) != entry.bits:
            raise SdoAbortedError(NOT_MAPPABLE)


def layouts_equal(a: list[TpdoLayout], b: list[TpdoLayout]) -> bool:
    """Same PDOs with the same identifiers and entries."""
    return [(x.cob_id, x.entries) for x in a] == [(y.cob_id, y.entries) for y in b]

