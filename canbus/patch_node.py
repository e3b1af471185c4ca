# canopen 2.4 ships py.typed but leaves LocalNode/SdoServer methods unannotated.
# mypy: disable-error-code="no-untyped-call"
"""One tactile patch as a CANopen device: object dictionary, NMT, heartbeat, EMCY, TPDOs.

The node does not own a clock or a signal source: :meth:`PatchNode.update` gives it
the patch's latest resistances, and :meth:`PatchNode.frames_on_sync` /
:meth:`PatchNode.frames_on_event` return the TPDO frames to send. ``canbus.patch_server``
drives many nodes from one source on one bus.
"""

from __future__ import annotations

import threading
from typing import Any

import canopen
import numpy as np
from numpy.typing import ArrayLike, NDArray

from canbus import codes
from canbus.emcy import FaultReporter
from canbus.heartbeat import HeartbeatProducer
from canbus.nmt_slave import OPERATIONAL, PRE_OPERATIONAL, RESET_COMMUNICATION, RESET_NODE, NmtSlave
from canbus.object_store import ObjectStore
from canbus.od import load_od
from canbus.pdo_codec import TPDO_COMM, TPDO_MAP
from canbus.tpdo import TpdoTable
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.errors import ConfigError

RESISTANCES, LSB, NOMINAL, CONSTANTS, STATUS = 0x2000, 0x2001, 0x2002, 0x2003, 0x2004
TPDO_COUNT = 7
_CONSTANT_FIELDS = ("youngs_modulus_pa", "resistivity_ohm_m", "length_m", "area_m2",
                    "max_strain", "full_scale_force_N", "taxel_pitch_m")
Frame = tuple[int, bytes]


def z_only_mapping() -> list[list[int]]:
    """Pillar z of each taxel, one grid row (3 taxels) per TPDO: 3 TPDOs."""
    return [[(RESISTANCES << 16) | ((3 * t + 1) << 8) | 16 for t in range(3 * row, 3 * row + 3)]
            for row in range(3)]


class PatchNode:
    """A 3x3 patch (node-ID 1..127) in mode ``"xyz"`` (27 values) or ``"z"`` (9 values)."""

    def __init__(self, node_id: int, *, mode: str = "xyz",
                 constants: SensorConstants = DEFAULT_CONSTANTS, serial: int = 0) -> None:
        if mode not in ("z", "xyz"):
            raise ConfigError("mode", f"must be 'z' or 'xyz', got {mode!r}")
        self.node_id = node_id
        self.mode = mode
        self.constants = constants
        self.serial = serial
        self.pillars = 1 if mode == "z" else 3
        self.store = ObjectStore(node_id, load_od("skin-patch", node_id))
        self.codes = np.full((9, 3), codes.OPEN, dtype=np.uint16)
        self.faults = FaultReporter()
        self.tpdo = TpdoTable(self.store, TPDO_COUNT)
        self.heartbeat = HeartbeatProducer(node_id)
        self.nmt = NmtSlave(node_id, on_reset=self._reset, on_state=self.heartbeat.set_state)
        self.network: canopen.Network | None = None
        self.lock = threading.RLock()
        self.store.add_read_callback(self._read_live)
        self.store.add_write_callback(self._written)
        self._apply_defaults()

    @property
    def state(self) -> int:
        return self.nmt.state

    def attach(self, network: canopen.Network) -> None:
        """Join ``network`` and boot: boot-up message, PRE-OPERATIONAL, heartbeat."""
        self.network = network
        self.store.associate_network(network)
        network.subscribe(0, self._on_nmt)
        self.nmt.boot(network)
        self.heartbeat.start(network, int(self.store.value(0x1017)), self.nmt.state)

    def detach(self) -> None:
        self.heartbeat.stop()
        if self.network is not None:
            self.network.unsubscribe(0, self._on_nmt)
            self.store.remove_network()
            self.network = None

    def update(self, resistance_ohm: ArrayLike) -> None:
        """Take the patch's resistances, shape ``(9, P)``: codes, taxel status, EMCY."""
        r = np.asarray(resistance_ohm, dtype=np.float64).reshape(9, -1)
        with self.lock:
            lsb = self.constants.resistance_lsb_ohm
            self.codes[:, : r.shape[1]] = codes.resistance_to_code(r, lsb)
            status = codes.taxel_status(self.codes, min(r.shape[1], self.pillars))
            emcy_live = self.nmt.state in (OPERATIONAL, PRE_OPERATIONAL)
            self.faults.update(status, self.network if emcy_live else None,
                               int(self.store.value(0x1014)))

    def values(self) -> NDArray[np.float64]:
        """The current values of the variables the TPDOs map, in codec column order."""
        flat: dict[int, NDArray[np.generic]] = {RESISTANCES: self.codes.reshape(-1),
                                               STATUS: self.faults.status}
        out = [flat[i][s - 1] if i in flat else self.faults.error_register
               for i, s in self.tpdo.codec.variables]
        return np.asarray(out, dtype=np.float64)[None, :]

    def frames_on_sync(self, counter: int) -> list[Frame]:
        with self.lock:
            if self.nmt.state != OPERATIONAL:
                return []
            payloads = self.tpdo.codec.pack(self.values())[0]
            return self._frames(self.tpdo.due_on_sync(counter, payloads), payloads)

    def frames_on_event(self, now: float) -> list[Frame]:
        with self.lock:
            if self.nmt.state != OPERATIONAL:
                return []
            payloads = self.tpdo.codec.pack(self.values())[0]
            return self._frames(self.tpdo.due_on_event(now, payloads), payloads)

    def _frames(self, due: list[int], payloads: NDArray[np.uint8]) -> list[Frame]:
        codec = self.tpdo.codec
        return [(int(codec.cob_ids[p]), payloads[p, : codec.sizes[p]].tobytes()) for p in due]

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self.lock:
            self.nmt.on_command(can_id, data, timestamp)
            reset = len(data) == 2 and data[0] in (RESET_NODE, RESET_COMMUNICATION)
            if reset and data[1] in (0, self.node_id) and self.network is not None:
                self.heartbeat.start(self.network, int(self.store.value(0x1017)), self.nmt.state)

    def _read_live(self, index: int, subindex: int, **_: Any) -> int | None:
        if index == RESISTANCES and subindex:
            return int(self.codes.reshape(-1)[subindex - 1])
        if index == STATUS and subindex:
            return int(self.faults.status[subindex - 1])
        if index == 0x1001:
            return self.faults.error_register
        return None

    def _written(self, index: int, **_: Any) -> None:
        if index == 0x1017:
            self.heartbeat.set_period(int(self.store.value(0x1017)))

    def _reset(self, application: bool) -> None:
        with self.lock:
            self.store.reset_area(0x1000, 0xFFFF if application else 0x1FFF)
            self._apply_defaults()
            self.heartbeat.stop()

    def _apply_defaults(self) -> None:
        """Power-on values that the EDS cannot know: constants, serial, z-only mapping."""
        c = self.constants
        self.store.store(0x1018, 4, self.serial)
        self.store.store(LSB, 0, c.resistance_lsb_ohm)
        for k, r0 in enumerate(np.tile(c.nominal_resistance_ohm, 9).tolist(), start=1):
            self.store.store(NOMINAL, k, r0)
        for s, name in enumerate(_CONSTANT_FIELDS, start=1):
            self.store.store(CONSTANTS, s, float(getattr(c, name)))
        if self.mode == "z":
            for n, entries in enumerate(z_only_mapping()):
                self.store.store(TPDO_MAP + n, 0, len(entries))
                for s, raw in enumerate(entries, start=1):
                    self.store.store(TPDO_MAP + n, s, raw)
            for n in range(3, TPDO_COUNT):
                cob = int(self.store.value(TPDO_COMM + n, 1))
                self.store.store(TPDO_COMM + n, 1, cob | 0x8000_0000)
        self.tpdo.reset()

