# canopen 2.4 ships py.typed but leaves LocalNode/SdoServer methods unannotated.
# mypy: disable-error-code="no-untyped-call"
"""One tactile patch as a CANopen device: object dictionary, NMT, heartbeat, EMCY, TPDOs.

The node does not own a clock or a signal source: :meth:`PatchNode.update` gives it
the patch's latest resistances, and :meth:`PatchNode.frames_on_sync` /
:meth:`PatchNode.frames_on_event` return the TPDO frames to send. ``canbus.device.patch_server``
drives many nodes from one source on one bus.
"""

from __future__ import annotations

import math
import threading
import weakref
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from canopen.sdo.exceptions import SdoAbortedError
from numpy.typing import ArrayLike, NDArray

from canbus import codes
from canbus.device.emcy import REGISTER_FAULT, FaultReporter
from canbus.device.local_device import TPDO_COUNT, LocalDevice
from canbus.device.nmt_slave import OPERATIONAL, PRE_OPERATIONAL
from canbus.pdo_codec import TPDO_COMM, TPDO_MAP, PdoCodec
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.errors import ConfigError

RESISTANCES, LSB, NOMINAL, CONSTANTS, STATUS = 0x2000, 0x2001, 0x2002, 0x2003, 0x2004
ANSWERED = 0x2006
INVALID_VALUE, ABOVE_LIMIT, BELOW_LIMIT = 0x0609_0030, 0x0609_0031, 0x0609_0032
"""The counter byte of the SYNC the TPDOs answer (0: none): mapped into a CAN FD answer, it
tells the master which cycle the answer belongs to."""
_CONSTANT_FIELDS = ("youngs_modulus_pa", "resistivity_ohm_m", "length_m", "area_m2",
                    "max_strain", "full_scale_force_N", "taxel_pitch_m")
Frame = tuple[int, bytes]
Due = Callable[["PatchNode", NDArray[np.uint8]], list[int]]
# A node's row: codes 0x2000 (27), status 0x2004 (9), 0x1001, 0x2006.
_ERROR_REGISTER_COLUMN, _ANSWERED_COLUMN = 36, 37


def z_only_mapping() -> list[list[int]]:
    """Pillar z of each taxel, one grid row (3 taxels) per TPDO: 3 TPDOs."""
    return [[(RESISTANCES << 16) | ((3 * t + 1) << 8) | 16 for t in range(3 * row, 3 * row + 3)]
            for row in range(3)]


class PatchNode(LocalDevice):
    """A 3x3 patch (node-ID 1..127) in mode ``"xyz"`` (27 values) or ``"z"`` (9 values)."""

    def __init__(self, node_id: int, *, mode: str = "xyz",
                 constants: SensorConstants = DEFAULT_CONSTANTS, serial: int = 0) -> None:
        if mode not in ("z", "xyz"):
            raise ConfigError("mode", f"must be 'z' or 'xyz', got {mode!r}")
        self.mode = mode
        self.constants = constants
        self.serial = serial
        self.pillars = 1 if mode == "z" else 3
        self.codes = np.full((9, 3), codes.OPEN, dtype=np.uint16)
        self.faults = FaultReporter()
        self.answered = 0  # 0x2006
        super().__init__(node_id, "skin-patch")
        self.store.validators.append(self._check_rest)

    def _check_rest(self, index: int, subindex: int, value: Any) -> None:
        """A master may write the patch's rest resistances (0x2002, a calibration's tare):
        each must be a finite resistance the ADC can read."""
        if index != NOMINAL or not subindex:
            return
        ohm = float(value)
        if not math.isfinite(ohm):
            raise SdoAbortedError(INVALID_VALUE)
        if ohm <= 0.0:
            raise SdoAbortedError(BELOW_LIMIT)
        if ohm >= codes.SATURATED * float(self.store.value(LSB)):
            raise SdoAbortedError(ABOVE_LIMIT)

    def update(self, resistance_ohm: ArrayLike) -> None:
        """Take the patch's resistances, shape ``(9, P)``: codes, taxel status, EMCY."""
        batch_update([self], np.asarray(resistance_ohm, dtype=np.float64).reshape(1, 9, -1))

    def _adopt(self, new_codes: NDArray[np.uint16], status: NDArray[np.uint8],
               changed: bool) -> None:
        """Take one sample's codes ``(9, 3)`` and taxel status (``changed``: it differs
        from the node's); EMCY for every taxel whose status changed."""
        with self.lock:
            self.codes[...] = new_codes
            if not changed:
                return  # nothing to report, nothing to adopt
            emcy_live = self.nmt.state in (OPERATIONAL, PRE_OPERATIONAL)
            self.faults.update(status, self.network if emcy_live else None,
                               int(self.store.value(0x1014)))

    def values(self) -> NDArray[np.float64]:
        """The current values of the variables the TPDOs map, in codec column order."""
        flat: dict[int, NDArray[np.generic]] = {RESISTANCES: self.codes.reshape(-1),
                                               STATUS: self.faults.status}
        other = {0x1001: self.faults.error_register, ANSWERED: self.answered}
        out = [flat[i][s - 1] if i in flat else other[i] for i, s in self.tpdo.codec.variables]
        return np.asarray(out, dtype=np.float64)[None, :]

    def frames_on_sync(self, counter: int, sync_byte: int = 0) -> list[Frame]:
        return batch_frames_on_sync([self], counter, sync_byte)

    def frames_on_event(self, now: float) -> list[Frame]:
        return batch_frames_on_event([self], now)

    def _on_state(self, state: int) -> None:
        super()._on_state(state)
        if state == OPERATIONAL:  # pack once now, not first in the first SYNC's answer
            _frames_locked([self], lambda node, payloads: [], 0)

    def _read_live(self, index: int, subindex: int, **_: Any) -> int | None:
        if index == RESISTANCES and subindex:
            return int(self.codes.reshape(-1)[subindex - 1])
        if index == STATUS and subindex:
            return int(self.faults.status[subindex - 1])
        if index == 0x1001:
            return self.faults.error_register
        if index == ANSWERED:
            return self.answered
        return None

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



def batch_update(nodes: Sequence[PatchNode], resistance_ohm: NDArray[np.float64]) -> None:
    """:meth:`PatchNode.update` of ``n`` nodes at once: ``(n, 9, P)`` ohms.

    One code conversion and one status computation per distinct (LSB, measured pillars);
    the fault reporter of a node runs only when its status changed.
    """
    r = resistance_ohm
    width = r.shape[2]
    groups: dict[tuple[float, int], list[int]] = {}
    for i, node in enumerate(nodes):
        key = (node.constants.resistance_lsb_ohm, min(width, node.pillars))
        groups.setdefault(key, []).append(i)
    for (lsb, measured), rows in groups.items():
        group = [nodes[i] for i in rows]
        new = codes.resistance_to_code(r if len(rows) == len(nodes) else r[rows], lsb)
        if width == 3:
            full = new
        else:  # the pillars not measured keep their codes
            full = np.stack([node.codes for node in group])
            full[:, :, :width] = new
        status = codes.taxel_status(full, measured)
        changed = (status != np.stack([node.faults.status for node in group])).any(axis=1)
        for node, node_codes, node_status, node_changed in zip(group, full, status,
                                                               changed.tolist(), strict=True):
            node._adopt(node_codes, node_status, node_changed)


def batch_frames_on_sync(nodes: Sequence[PatchNode], counter: int,
                         sync_byte: int = 0) -> list[Frame]:
    """:meth:`PatchNode.frames_on_sync` of ``nodes``, in node order: ``counter`` counts the
    SYNCs the nodes have seen (for transmission types 1..240), ``sync_byte`` is the SYNC's
    own counter byte (0 without one), the answer's 0x2006."""
    return batch_frames(nodes, lambda node, payloads: node.tpdo.due_on_sync(counter, payloads),
                        sync_byte)


def batch_frames_on_event(nodes: Sequence[PatchNode], now: float) -> list[Frame]:
    """:meth:`PatchNode.frames_on_event` of ``nodes``, in node order."""
    return batch_frames(nodes, lambda node, payloads: node.tpdo.due_on_event(now, payloads))


def batch_frames(nodes: Sequence[PatchNode], due: Due, sync_byte: int = 0) -> list[Frame]:
    """The TPDO frames that ``due(node, payloads)`` selects, of every OPERATIONAL node.

    Nodes whose TPDOs are mapped alike are packed by one ``PdoCodec.pack`` call; every
    node's lock is held throughout, so each sees one consistent sample and mapping.
    """
    held: list[threading.RLock] = []
    try:
        for node in nodes:
            node.lock.acquire()
            held.append(node.lock)
        for node in nodes:
            node.answered = sync_byte
        return _frames_locked([node for node in nodes if node.nmt.state == OPERATIONAL], due,
                              sync_byte)
    finally:
        for lock in reversed(held):
            lock.release()


def _frames_locked(live: list[PatchNode], due: Due, sync_byte: int) -> list[Frame]:
    if not live:
        return []
    n = len(live)
    status = np.stack([node.faults.status for node in live])
    error_register = np.where(status.any(axis=1), REGISTER_FAULT, 0)  # FaultReporter's 0x1001
    rows = np.concatenate([np.stack([node.codes for node in live]).reshape(n, 27), status,
                           error_register[:, None], np.full((n, 1), sync_byte)], axis=1,
                          dtype=np.int64)
    groups: dict[_Layout, list[int]] = {}
    for i, node in enumerate(live):
        groups.setdefault(_layout(node.tpdo.codec), []).append(i)
    out: list[list[Frame]] = [[] for _ in live]
    for layout, members in groups.items():
        chosen = rows if len(members) == n else rows[members]
        payloads = live[members[0]].tpdo.codec.pack(chosen[:, layout.gather])
        width = payloads.shape[2]
        blob, stride, sizes = payloads.tobytes(), width * len(layout.sizes), layout.sizes
        for m, i in enumerate(members):
            cob_ids = live[i].tpdo.codec.cob_ids.tolist()
            at = m * stride
            out[i] = [(cob_ids[p], blob[at + width * p:at + width * p + sizes[p]])
                      for p in sorted(due(live[i], payloads[m]), key=cob_ids.__getitem__)]
    return [frame for frames in out for frame in frames]


class _Layout:
    """A TPDO mapping shape: codecs mapped alike share one (by identity)."""

    __slots__ = ("__weakref__", "gather", "sizes")

    def __init__(self, codec: PdoCodec) -> None:
        self.sizes = tuple(int(size) for size in codec.sizes)
        columns = {RESISTANCES: 0, STATUS: 27}
        single = {0x1001: _ERROR_REGISTER_COLUMN, ANSWERED: _ANSWERED_COLUMN}
        self.gather = np.array([columns[i] + s - 1 if i in columns else single[i]
                                for i, s in codec.variables], dtype=np.intp)


_LAYOUTS: weakref.WeakKeyDictionary[PdoCodec, _Layout] = weakref.WeakKeyDictionary()
_SHAPES: dict[tuple[Any, ...], _Layout] = {}


def _layout(codec: PdoCodec) -> _Layout:
    """The codec's mapping shape, computed once per codec and shared by equal mappings."""
    layout = _LAYOUTS.get(codec)
    if layout is None:
        key = tuple(lay.entries for lay in codec.layouts)
        layout = _SHAPES.get(key)
        if layout is None:
            layout = _SHAPES[key] = _Layout(codec)
        _LAYOUTS[codec] = layout
    return layout
