# canopen 2.4 ships py.typed but leaves LocalNode/SdoServer methods unannotated.
# mypy: disable-error-code="no-untyped-call"
"""The object dictionary of a device: canopen's ``LocalNode`` with CiA 301 write checks.

canopen's ``LocalNode.set_data`` checks access and (for numbers) size, but answers any
size mismatch with 0x06070010, never checks LowLimit/HighLimit, and lets array
subindexes past sub-index 0's count through (``ODArray`` invents them). Here:

* missing object 0x06020000, missing subindex 0x06090011;
* read a write-only object 0x06010001, write a read-only one 0x06010002;
* too many bytes 0x06070012, too few 0x06070013;
* above HighLimit 0x06090031, below LowLimit 0x06090032;
* service-specific rules (PDO parameters, heartbeat) run as validators before the
  value is stored, and write callbacks after it is stored.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import canopen
from canopen import LocalNode
from canopen.objectdictionary import NUMBER_TYPES, ODArray, ODVariable
from canopen.sdo.exceptions import SdoAbortedError

from canbus.device.sdo_server import StrictSdoServer

logger = logging.getLogger(__name__)

Validator = Callable[[int, int, Any], None]
"""``validate(index, subindex, value)``: raise ``SdoAbortedError`` to refuse a write."""


class ObjectStore(LocalNode):
    """Object values of one node, served by a :class:`StrictSdoServer`."""

    def __init__(self, node_id: int, od: canopen.ObjectDictionary) -> None:
        super().__init__(node_id, od)
        # canopen's LocalNode registers its own NmtSlave for 0x1017; our heartbeat
        # module owns that object, so start from no callbacks.
        self._write_callbacks.clear()
        self.sdo = StrictSdoServer(0x600 + node_id, 0x580 + node_id, self)
        self.validators: list[Validator] = []

    def associate_network(self, network: canopen.Network) -> None:
        self.network = network
        self.sdo.network = network
        network.subscribe(self.sdo.rx_cobid, self.sdo.on_request)

    def remove_network(self) -> None:
        self.network.unsubscribe(self.sdo.rx_cobid, self.sdo.on_request)
        self.network = canopen.network._UNINITIALIZED_NETWORK
        self.sdo.network = self.network

    def _find_object(self, index: int, subindex: int) -> ODVariable:
        if index not in self.object_dictionary:
            raise SdoAbortedError(0x0602_0000)
        obj = self.object_dictionary[index]
        if isinstance(obj, ODVariable):
            if subindex != 0:
                raise SdoAbortedError(0x0609_0011)
            return obj
        if isinstance(obj, ODArray):
            count = int(self.value(index, 0)) if subindex else 0
            if subindex not in obj.subindices and not 0 < subindex <= count:
                raise SdoAbortedError(0x0609_0011)
        elif subindex not in obj.subindices:
            raise SdoAbortedError(0x0609_0011)
        return obj[subindex]

    def check_value(self, index: int, subindex: int, data: bytes) -> Any:
        """The value ``data`` writes, if its size and limits are the object's (else the
        abort): the checks of any write, before the services' own rules."""
        obj = self._find_object(index, subindex)
        if obj.data_type not in NUMBER_TYPES:
            return data
        if 8 * len(data) > len(obj):
            raise SdoAbortedError(0x0607_0012)
        if 8 * len(data) < len(obj):
            raise SdoAbortedError(0x0607_0013)
        value = obj.decode_raw(data)
        assert isinstance(value, int | float)
        if obj.max is not None and value > obj.max:
            raise SdoAbortedError(0x0609_0031)
        if obj.min is not None and value < obj.min:
            raise SdoAbortedError(0x0609_0032)
        return value

    def set_data(self, index: int, subindex: int, data: bytes,
                 check_writable: bool = False) -> None:
        obj = self._find_object(index, subindex)
        if check_writable and not obj.writable:
            raise SdoAbortedError(0x0601_0002)
        value = self.check_value(index, subindex, data)
        for validate in self.validators:
            validate(index, subindex, value)
        self.data_store.setdefault(index, {})[subindex] = bytes(data)
        for callback in self._write_callbacks:
            callback(index=index, subindex=subindex, od=obj, data=data)

    def value(self, index: int, subindex: int = 0) -> Any:
        """The current value of an object, decoded."""
        obj = self.object_dictionary[index]
        var = obj if isinstance(obj, ODVariable) else obj[subindex]
        return var.decode_raw(self.get_data(index, subindex))

    def store(self, index: int, subindex: int, value: Any) -> None:
        """Set a value as the application (no access check, no validators, no callbacks)."""
        obj = self.object_dictionary[index]
        var = obj if isinstance(obj, ODVariable) else obj[subindex]
        self.data_store.setdefault(index, {})[subindex] = var.encode_raw(value)

    def reset_area(self, first: int, last: int) -> None:
        """Forget written values of objects ``first..last``: they fall back to the EDS."""
        for index in [i for i in self.data_store if first <= i <= last]:
            del self.data_store[index]
