# canopen 2.4 ships py.typed but leaves LocalNode/SdoServer methods unannotated.
# mypy: disable-error-code="no-untyped-call"
"""What every CANopen device of this package shares: object store, TPDOs, NMT, heartbeat.

:class:`PatchNode` and :class:`ForceNode` are devices; a subclass sets its own fields,
then calls ``super().__init__``, and provides ``_read_live`` (live object values),
``_apply_defaults`` (power-on values the EDS cannot know) and optionally
``_clear_application`` (what an NMT reset node also clears).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import canopen

from canbus.device.heartbeat import HeartbeatProducer
from canbus.device.nmt_slave import OPERATIONAL, RESET_COMMUNICATION, RESET_NODE, NmtSlave
from canbus.device.object_store import ObjectStore
from canbus.device.tpdo import TpdoTable
from canbus.od import load_od
from canbus.txmessage import fd_capable

TPDO_COUNT = 7


class LocalDevice:
    """A CANopen device on a :class:`canopen.Network`, described by a shipped EDS."""

    def __init__(self, node_id: int, eds: str, tpdo_count: int = TPDO_COUNT) -> None:
        self.node_id = node_id
        self.store = ObjectStore(node_id, load_od(eds, node_id))
        self.tpdo = TpdoTable(self.store, tpdo_count)
        self.heartbeat = HeartbeatProducer(node_id)
        self.nmt = NmtSlave(node_id, on_reset=self._reset, on_state=self._on_state)
        self.network: canopen.Network | None = None
        self.lock = threading.RLock()
        self.on_cob_ids_changed: Callable[[], None] | None = None
        """Called after a write or reset that may change :meth:`transmitted_cob_ids`."""
        self.store.add_read_callback(self._read_live)
        self.store.add_write_callback(self._written)
        self._apply_defaults()

    @property
    def state(self) -> int:
        return self.nmt.state

    def attach(self, network: canopen.Network) -> None:
        """Join ``network`` and boot: boot-up message, PRE-OPERATIONAL, heartbeat, SDO server.

        Under the device's lock: a master may answer the boot-up at once (an SDO write
        of 0x1017 on the network's thread), and must find the heartbeat started.
        """
        with self.lock:
            self.network = network
            self.tpdo.max_bytes = 64 if fd_capable(network.bus) else 8
            self.store.associate_network(network)
            network.subscribe(0, self._on_nmt)
            self.nmt.boot(network)
            self.heartbeat.start(network, int(self.store.value(0x1017)), self.nmt.state)

    def transmitted_cob_ids(self) -> set[int]:
        """The COB-IDs this device sends from: boot-up and heartbeat, EMCY, SDO responses
        and its valid TPDOs (as mapped now)."""
        out = {0x700 + self.node_id, int(self.store.sdo.tx_cobid)}
        if 0x1014 in self.store.object_dictionary:
            emcy = int(self.store.value(0x1014))
            if not emcy & 0x8000_0000:
                out.add(emcy & 0x7FF)
        out.update(int(c) for c in self.tpdo.codec.cob_ids.tolist())
        return out

    def detach(self) -> None:
        with self.lock:
            self.heartbeat.stop()
            if self.network is not None:
                self.network.unsubscribe(0, self._on_nmt)
                self.store.remove_network()
                self.network = None

    def _read_live(self, index: int, subindex: int, **_: Any) -> int | None:
        return None

    def _apply_defaults(self) -> None:
        self.tpdo.reset()

    def _clear_application(self) -> None:
        """What a reset node (not a reset communication) clears besides the objects."""

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self.lock:
            self.nmt.on_command(can_id, data, timestamp)
            reset = len(data) == 2 and data[0] in (RESET_NODE, RESET_COMMUNICATION)
            if reset and data[1] in (0, self.node_id) and self.network is not None:
                self.heartbeat.start(self.network, int(self.store.value(0x1017)), self.nmt.state)

    def _on_state(self, state: int) -> None:
        self.heartbeat.set_state(state)
        if state == OPERATIONAL:  # read the PDO mapping now, not in the first SYNC's answer
            _ = self.tpdo.codec

    def _written(self, index: int, **_: Any) -> None:
        if index == 0x1017:
            with self.lock:  # after attach() started the heartbeat: never two tasks at once
                self.heartbeat.set_period(int(self.store.value(0x1017)))
        elif index in (0x1014, 0x1200) or 0x1800 <= index <= 0x19FF:
            self._cob_ids_changed()

    def _cob_ids_changed(self) -> None:
        if self.on_cob_ids_changed is not None:
            self.on_cob_ids_changed()

    def _reset(self, application: bool) -> None:
        with self.lock:
            self.store.reset_area(0x1000, 0xFFFF if application else 0x1FFF)
            if application:
                self._clear_application()
            self._apply_defaults()
            self.heartbeat.stop()
        self._cob_ids_changed()
