# canopen 2.4 ships py.typed but leaves LocalNode/SdoServer methods unannotated.
# mypy: disable-error-code="no-untyped-call"
"""0x1010 store parameters and 0x1011 restore default parameters (CiA 301).

Writing the signature "save" (0x65766173) to 0x1010 sub 1 (all), 2 (communication,
0x1000..0x1FFF), 3 (application, 0x6000..0x9FFF) or 4 (manufacturer, 0x2000..0x5FFF)
keeps the written values of that area in the device's non-volatile store
(``canbus.device.nv_store``); "load" (0x64616F6C) to 0x1011 forgets them, so the defaults
come back at the next reset (or power-on). Any other value aborts with 0x08000020; reading
a sub-index gives 1 (the device saves on command). What is saved is every writable object
of the area whose value is not its default (the error history 0x1003 is not a parameter).
"""

from __future__ import annotations

import logging
from typing import Any

from canopen.objectdictionary import ODArray, ODRecord, ODVariable
from canopen.sdo.exceptions import SdoAbortedError

from canbus.device.nv_store import NvStore, NvStoreError
from canbus.device.object_store import ObjectStore

STORE, RESTORE = 0x1010, 0x1011
SAVE, LOAD = 0x6576_6173, 0x6461_6F6C
logger = logging.getLogger(__name__)
CANNOT_STORE = 0x0800_0020
NOT_PARAMETERS = (0x1003, STORE, RESTORE)
COMMUNICATION, MANUFACTURER, APPLICATION = (0x1000, 0x1FFF), (0x2000, 0x5FFF), (0x6000, 0x9FFF)
AREAS = {1: (COMMUNICATION, MANUFACTURER, APPLICATION), 2: (COMMUNICATION,),
         3: (APPLICATION,), 4: (MANUFACTURER,)}


def variables(store: ObjectStore) -> dict[tuple[int, int], ODVariable]:
    """Every variable of the device's dictionary by (index, subindex)."""
    out: dict[tuple[int, int], ODVariable] = {}
    for index, obj in store.object_dictionary.items():
        if isinstance(obj, ODVariable):
            out[(index, 0)] = obj
        elif isinstance(obj, ODArray | ODRecord):
            out.update({(index, sub): var for sub, var in obj.subindices.items()})
    return out


class StoreRestore:
    """The store/restore service of one device, over its object store and ``nv``."""

    def __init__(self, nv: NvStore, exclude: frozenset[int] = frozenset()) -> None:
        self.nv = nv
        self.exclude = NOT_PARAMETERS + tuple(exclude)
        self.store: ObjectStore | None = None

    def attach(self, store: ObjectStore) -> None:
        self.store = store
        store.validators.append(self._validate)
        store.add_write_callback(self._written)

    def _validate(self, index: int, subindex: int, value: Any) -> None:
        expected = SAVE if index == STORE else LOAD
        if index in (STORE, RESTORE) and subindex and (value != expected or
                                                        subindex not in AREAS):
            raise SdoAbortedError(CANNOT_STORE)

    def _written(self, index: int, subindex: int, **_: Any) -> None:
        if index not in (STORE, RESTORE) or not subindex or self.store is None:
            return
        self.store.data_store[index].pop(subindex, None)  # reads keep answering 1
        try:
            for first, last in AREAS[subindex]:
                if index == STORE:
                    self.nv.save_objects(self.saved_values(first, last), first, last)
                else:
                    self.nv.forget_objects(first, last)
        except OSError as err:  # the state file cannot be written: the SDO write aborts
            logger.warning("cannot write %s: %s", self.nv.path, err)
            raise SdoAbortedError(CANNOT_STORE) from err

    def saved_values(self, first: int, last: int) -> dict[tuple[int, int], bytes]:
        """The area's writable objects whose value differs from the EDS default."""
        assert self.store is not None
        out = {}
        for (index, sub), var in variables(self.store).items():
            if not first <= index <= last or index in self.exclude or not var.writable:
                continue
            raw = self.store.data_store.get(index, {}).get(sub)
            if raw is not None and (var.default is None or
                                    bytes(raw) != var.encode_raw(var.default)):
                out[(index, sub)] = bytes(raw)
        return out

    def restore_saved(self) -> None:
        """Put the stored values in place (at power-on and after a reset); a stored object
        the dictionary has not, or cannot take, refuses the store with its key."""
        assert self.store is not None
        known = variables(self.store)
        for (index, sub), raw in sorted(self.nv.content.objects.items()):
            key = f"objects.{index:04X}:{sub:02X}"
            var = known.get((index, sub))
            if var is None or not var.writable or index in self.exclude:
                raise NvStoreError(f"{self.nv.path or 'store'}.{key}",
                                   "no such writable parameter on this device")
            try:
                self.store.check_value(index, sub, raw)
            except SdoAbortedError as err:
                raise NvStoreError(f"{self.nv.path or 'store'}.{key}",
                                   f"refused by the device (SDO abort 0x{err.code:08X})") from err
            self.store.data_store.setdefault(index, {})[sub] = raw
