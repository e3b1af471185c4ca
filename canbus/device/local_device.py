# canopen 2.4 ships py.typed but leaves LocalNode/SdoServer methods unannotated.
# mypy: disable-error-code="no-untyped-call"
"""What every CANopen device of this package shares: object store, TPDOs, NMT, heartbeat,
the error history (0x1003), store/restore (0x1010/0x1011) and its node-ID.

:class:`PatchNode` and :class:`ForceNode` are devices; a subclass sets its own fields,
then calls ``super().__init__``, and provides ``_read_live`` (live object values),
``_apply_defaults`` (power-on values the EDS cannot know), ``_on_store_built`` (its own
validators on a new object store) and optionally ``_clear_application`` (what an NMT
reset node also clears).

The node-ID can change (LSS, CiA 305): node-ID 0xFF is a device not configured yet, which
sends nothing and waits for LSS (:attr:`lss`); a node-ID that LSS sets takes effect when
an unconfigured device leaves LSS configuration, or at the next NMT reset. The device
then builds its object store anew for that node-ID (the ``$NODEID`` defaults of its EDS)
and boots with it. What the non-volatile store (``nv``) holds is put back at power-on and
after every reset: a stored node-ID, and the objects 0x1010 saved.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import canopen
from canopen.objectdictionary import ODRecord

from canbus.device import comm_objects
from canbus.device.error_history import ErrorHistory
from canbus.device.heartbeat import HeartbeatProducer
from canbus.device.nmt_slave import OPERATIONAL, RESET_COMMUNICATION, RESET_NODE, NmtSlave
from canbus.device.nv_store import NvStore
from canbus.device.object_store import ObjectStore
from canbus.device.store_restore import StoreRestore
from canbus.device.tpdo import TpdoTable
from canbus.identity import Identity
from canbus.od import load_od
from canbus.txmessage import fd_capable
from skin.inputs import fields
from skin.inputs.fields import UNCONFIGURED

if TYPE_CHECKING:
    from canbus.device.lss_slave import LssSlave

TPDO_COUNT = 7
ERROR_HISTORY_DEPTH = 8
COMMUNICATION_ERROR = 0x8100
"""EMCY error code "communication, generic", kept in 0x1003 at a communication error."""


@functools.lru_cache(maxsize=8)
def eds_identity(eds: str) -> tuple[int, int, int]:
    """Vendor-ID, product code and revision (0x1018 sub 1..3) of a shipped EDS."""
    identity = load_od(eds, 1)[0x1018]
    assert isinstance(identity, ODRecord)
    vendor, product, revision = (int(identity[s].default or 0) for s in (1, 2, 3))
    return vendor, product, revision


class LocalDevice:
    """A CANopen device on a :class:`canopen.Network`, described by a shipped EDS."""

    NOT_STORED: frozenset[int] = frozenset()
    """Command objects of the device that 0x1010 does not keep."""

    def __init__(self, node_id: int, eds: str, tpdo_count: int = TPDO_COUNT, *,
                 serial: int = 0, nv: NvStore | None = None) -> None:
        fields.node_id(node_id, "node_id", unconfigured=True)
        self.eds = eds
        self.tpdo_count = tpdo_count
        self.identity = Identity(*eds_identity(eds), serial=serial)
        self.nv = nv if nv is not None else NvStore(None, self.identity)
        if self.nv.content.node_id is not None:
            node_id = self.nv.content.node_id
        self.lock = threading.RLock()
        self.network: canopen.Network | None = None
        self.lss: LssSlave | None = None
        self.on_cob_ids_changed: Callable[[], None] | None = None
        """Called after a write or reset that may change :meth:`transmitted_cob_ids`."""
        self.on_node_id_changed: Callable[[LocalDevice], None] | None = None
        """Called (device lock held) after the device took a new node-ID."""
        self.history = ErrorHistory(ERROR_HISTORY_DEPTH)
        self.store_restore = StoreRestore(self.nv, self.NOT_STORED)
        self._build(node_id)

    @property
    def state(self) -> int:
        return self.nmt.state

    @property
    def configured(self) -> bool:
        """The device has a node-ID (1..127): it takes part in NMT, SDO and PDO traffic."""
        return self.node_id != UNCONFIGURED

    def _build(self, node_id: int) -> None:
        """The object store and services for ``node_id``, at their power-on values."""
        self.node_id = node_id
        od_id = node_id if self.configured else 1  # an unconfigured device sends nothing
        self.store = ObjectStore(od_id, load_od(self.eds, od_id))
        self.tpdo = TpdoTable(self.store, self.tpdo_count)
        self.heartbeat = HeartbeatProducer(od_id)
        self.nmt = NmtSlave(od_id, on_reset=self._reset, on_state=self._on_state)
        self.history.attach(self.store)
        self.store_restore.attach(self.store)
        self.store.validators.append(comm_objects.validate)
        self.store.add_read_callback(self._read_live)
        self.store.add_write_callback(self._written)
        self._on_store_built()
        self._power_on_values()

    def _power_on_values(self) -> None:
        self._apply_defaults()
        self.store.store(0x1018, 4, self.identity.serial)
        self.store_restore.restore_saved()
        self.tpdo.reset()

    def attach(self, network: canopen.Network) -> None:
        """Join ``network``: LSS, and for a configured device boot: boot-up message,
        PRE-OPERATIONAL, heartbeat, SDO server.

        Under the device's lock: a master may answer the boot-up at once (an SDO write
        of 0x1017 on the network's thread), and must find the heartbeat started.
        """
        with self.lock:
            self.network = network
            if self.lss is not None:
                self.lss.attach(network)
            self._join(network)

    def _join(self, network: canopen.Network) -> None:
        if not self.configured:
            return  # waits for LSS: no boot-up, no SDO, no heartbeat
        self.tpdo.max_bytes = 64 if fd_capable(network.bus) else 8
        self.store.associate_network(network)
        network.subscribe(0, self._on_nmt)
        self.nmt.boot(network)
        self.heartbeat.start(network, int(self.store.value(0x1017)), self.nmt.state)

    def _leave(self) -> None:
        self.heartbeat.stop()
        if self.network is not None and self.configured:
            self.network.unsubscribe(0, self._on_nmt)
            self.store.remove_network()

    def transmitted_cob_ids(self) -> set[int]:
        """The COB-IDs this device sends from: boot-up and heartbeat, EMCY, SDO responses
        and its valid TPDOs (as mapped now); LSS responses if it answers LSS."""
        out = {0x7E4} if self.lss is not None else set()
        if not self.configured:
            return out
        out |= {0x700 + self.node_id, int(self.store.sdo.tx_cobid)}
        if 0x1014 in self.store.object_dictionary:
            emcy = int(self.store.value(0x1014))
            if not emcy & 0x8000_0000:
                out.add(emcy & 0x7FF)
        out.update(int(c) for c in self.tpdo.codec.cob_ids.tolist())
        return out

    def sync_cob_id(self) -> int:
        """The CAN-ID of the SYNC the device consumes (0x1005 bits 0..10)."""
        if comm_objects.COB_ID_SYNC not in self.store.object_dictionary:
            return 0x80
        return int(self.store.value(comm_objects.COB_ID_SYNC)) & 0x7FF

    def detach(self) -> None:
        with self.lock:
            if self.lss is not None:
                self.lss.detach()
            if self.network is not None:
                self._leave()
                self.network = None

    def adopt_node_id(self, node_id: int) -> None:
        """Take ``node_id`` now (LSS, or an NMT reset with another node-ID pending): the
        object store anew for it and, on a network, a new boot (none for 0xFF)."""
        with self.lock:
            network = self.network
            if network is not None:
                self._leave()
            self._build(node_id)
            if network is not None:
                self._join(network)
            if self.on_node_id_changed is not None:
                self.on_node_id_changed(self)
        self._cob_ids_changed()

    def communication_error(self) -> None:
        """The device could not send (bus-off, a failed send): 0x1003 keeps it and the
        device changes state as 0x1029 sub 1 says."""
        with self.lock:
            if not self.configured:
                return
            self.history.push(COMMUNICATION_ERROR)
            if comm_objects.ERROR_BEHAVIOUR not in self.store.object_dictionary:
                return
            behaviour = int(self.store.value(comm_objects.ERROR_BEHAVIOUR, 1))
            target = comm_objects.communication_error_state(behaviour, self.nmt.state)
            self.nmt.enter(target)

    def _read_live(self, index: int, subindex: int, **_: Any) -> int | None:
        return None

    def _apply_defaults(self) -> None:
        self.tpdo.reset()

    def _on_store_built(self) -> None:
        """Add the device's own validators and callbacks to a new :attr:`store`."""

    def _clear_application(self) -> None:
        """What a reset node (not a reset communication) clears besides the objects."""

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self.lock:
            reset = len(data) == 2 and data[0] in (RESET_NODE, RESET_COMMUNICATION) \
                and data[1] in (0, self.node_id)
            pending = self.lss.pending_node_id if self.lss is not None else self.node_id
            if reset and pending != self.node_id:
                if data[0] == RESET_NODE:
                    self._clear_application()
                self.adopt_node_id(pending)
                return
            self.nmt.on_command(can_id, data, timestamp)
            if reset and self.network is not None:
                self.heartbeat.start(self.network, int(self.store.value(0x1017)), self.nmt.state)

    def _on_state(self, state: int) -> None:
        self.heartbeat.set_state(state)
        if state == OPERATIONAL:  # read the PDO mapping now, not in the first SYNC's answer
            _ = self.tpdo.codec

    def _written(self, index: int, **_: Any) -> None:
        if index == 0x1017:
            with self.lock:  # after attach() started the heartbeat: never two tasks at once
                self.heartbeat.set_period(int(self.store.value(0x1017)))
        elif index in (0x1005, 0x1014, 0x1200) or 0x1800 <= index <= 0x19FF:
            self._cob_ids_changed()

    def _cob_ids_changed(self) -> None:
        if self.on_cob_ids_changed is not None:
            self.on_cob_ids_changed()

    def _reset(self, application: bool) -> None:
        with self.lock:
            self.store.reset_area(0x1000, 0xFFFF if application else 0x1FFF)
            if application:
                self._clear_application()
                self.history.clear()
            self._power_on_values()
            self.heartbeat.stop()
        self._cob_ids_changed()
