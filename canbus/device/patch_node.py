# canopen 2.4 ships py.typed but leaves LocalNode/SdoServer methods unannotated.
# mypy: disable-error-code="no-untyped-call"
"""One tactile patch as a CANopen device: object dictionary, NMT, heartbeat, EMCY, TPDOs.

The node does not own a clock or a signal source: :meth:`PatchNode.update` gives it
the patch's latest resistances, and :meth:`PatchNode.frames_on_sync` /
:meth:`PatchNode.frames_on_event` return the TPDO frames to send. ``canbus.device.patch_server``
drives many nodes from one source on one bus.
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np
from canopen.sdo.exceptions import SdoAbortedError
from numpy.typing import ArrayLike, NDArray

from canbus import codes
from canbus.device.emcy import REGISTER_FAULT, FaultReporter
from canbus.device.local_device import TPDO_COUNT, LocalDevice
from canbus.device.lss_slave import LssSlave
from canbus.device.nmt_slave import OPERATIONAL, PRE_OPERATIONAL
from canbus.device.nv_store import NvStore
from canbus.device.tpdo import EVENT_DRIVEN
from canbus.patch_constants import LSB_SCALE, R0_SCALE, constant_counts
from canbus.pdo_codec import TPDO_COMM, TPDO_MAP, PdoCodec
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.errors import ConfigError

RESISTANCES, LSB, NOMINAL, CONSTANTS, STATUS = 0x2000, 0x2001, 0x2002, 0x2003, 0x2004
ANSWERED = 0x2006
INVALID_VALUE, ABOVE_LIMIT, BELOW_LIMIT = 0x0609_0030, 0x0609_0031, 0x0609_0032
"""The counter byte of the SYNC the TPDOs answer (0: none): mapped into a CAN FD answer, it
tells the master which cycle the answer belongs to."""
Frame = tuple[int, bytes]
Due = Callable[["PatchNode", Sequence[bytes]], list[int]]


def z_only_mapping() -> list[list[int]]:
    """Pillar z of each taxel, one grid row (3 taxels) per TPDO: 3 TPDOs."""
    return [[(RESISTANCES << 16) | ((3 * t + 1) << 8) | 16 for t in range(3 * row, 3 * row + 3)]
            for row in range(3)]


class PatchNode(LocalDevice):
    """A 3x3 patch (node-ID 1..127, or 0xFF: waiting for LSS) in mode ``"xyz"`` (27 values)
    or ``"z"`` (9 values), with its serial number (0x1018 sub 4) and non-volatile store."""

    def __init__(self, node_id: int, *, mode: str = "xyz",
                 constants: SensorConstants = DEFAULT_CONSTANTS, serial: int = 0,
                 nv: NvStore | None = None) -> None:
        if mode not in ("z", "xyz"):
            raise ConfigError("mode", f"must be 'z' or 'xyz', got {mode!r}")
        self.mode = mode
        self.constants = constants
        self.serial = serial
        self.pillars = 1 if mode == "z" else 3
        self.codes = np.full((9, 3), codes.OPEN, dtype=np.uint16)
        self.faults = FaultReporter()
        self.answered = 0  # 0x2006
        super().__init__(node_id, "skin-patch", serial=serial, nv=nv)
        self.lss = LssSlave(self)

    def _on_store_built(self) -> None:
        self.store.validators.append(self._check_rest)

    def _check_rest(self, index: int, subindex: int, value: Any) -> None:
        """A master may write the patch's rest resistances (0x2002 in mOhm, a calibration's
        tare): each must be a resistance the ADC can read (above 0, below its full scale)."""
        if index != NOMINAL or not subindex:
            return
        if int(value) <= 0:
            raise SdoAbortedError(BELOW_LIMIT)
        lsb_ohm = LSB_SCALE.to_si(int(self.store.value(LSB)))
        if R0_SCALE.to_si(int(value)) >= codes.SATURATED * lsb_ohm:
            raise SdoAbortedError(ABOVE_LIMIT)

    def update(self, resistance_ohm: ArrayLike) -> None:
        """Take the patch's resistances, shape ``(9, P)``: codes, taxel status, EMCY."""
        batch_update([self], np.asarray(resistance_ohm, dtype=np.float64).reshape(1, 9, -1))

    def adopt(self, new_codes: NDArray[np.uint16], status: NDArray[np.uint8],
               changed: bool) -> None:
        """Take one sample's codes ``(9, 3)`` and taxel status (``changed``: it differs
        from the node's); EMCY for every taxel whose status changed. What :meth:`update`
        does after the conversion, for callers that convert many nodes at once."""
        with self.lock:
            self.codes[...] = new_codes
            if not changed:
                return  # nothing to report, nothing to adopt
            emcy_live = self.nmt.state in (OPERATIONAL, PRE_OPERATIONAL)
            self.faults.update(status, self.network if emcy_live else None,
                               int(self.store.value(0x1014)), self.history)

    def halt(self) -> None:
        """The patch can no longer take samples (its source failed): EMCY 0x6100, and the
        error register says so; its server answers no SYNC for it from then on."""
        with self.lock:
            emcy_live = self.nmt.state in (OPERATIONAL, PRE_OPERATIONAL)
            self.faults.halt(self.network if emcy_live else None,
                             int(self.store.value(0x1014)), self.history)

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
        if state == OPERATIONAL:  # plan now, not first in the first SYNC's answer
            answer_plan(self)

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
        """Power-on values that the EDS cannot know: constants, z-only mapping."""
        c = self.constants
        self.store.store(LSB, 0, LSB_SCALE.to_count(c.resistance_lsb_ohm))
        for k, r0 in enumerate(np.tile(c.nominal_resistance_ohm, 9).tolist(), start=1):
            self.store.store(NOMINAL, k, R0_SCALE.to_count(r0))
        for s, count in enumerate(constant_counts(c), start=1):
            self.store.store(CONSTANTS, s, count)
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
            node.adopt(node_codes, node_status, node_changed)


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
    """The TPDO frames that ``due(node, payloads)`` selects, of every OPERATIONAL node, each
    node's in ascending COB-ID order (as a CAN controller sends its queued frames).

    Every node's lock is held throughout, so each sees one consistent sample and mapping.
    """
    with locked(nodes):
        for node in nodes:
            node.answered = sync_byte
        live = [node for node in nodes if node.nmt.state == OPERATIONAL]
        plans = [answer_plan(node) for node in live]
        out: list[Frame] = []
        for node, plan, payloads in zip(live, plans, pack_payloads(live, plans=plans),
                                        strict=True):
            chosen = set(due(node, payloads))
            out += [(plan.cob_ids[p], payloads[p]) for p in plan.order if p in chosen]
        return out


@contextmanager
def locked(nodes: Sequence[PatchNode]) -> Iterator[None]:
    """Hold every node's lock (in order) for the block."""
    held: list[threading.RLock] = []
    try:
        for node in nodes:
            node.lock.acquire()
            held.append(node.lock)
        yield
    finally:
        for lock in reversed(held):
            lock.release()


# A node's row of bytes, from which every mapping of skin-patch.eds is gathered: the codes
# 0x2000 (27 x UNSIGNED16, little-endian), the taxel status 0x2004 (9 x UNSIGNED8), the
# error register 0x1001 and 0x2006 (the answered SYNC's counter byte).
_ROW = {RESISTANCES: (0, 2), STATUS: (54, 1), 0x1001: (63, 1), ANSWERED: (64, 1)}
_ROW_BYTES = 65


def pack_payloads(nodes: Sequence[PatchNode], codes: NDArray[np.uint16] | None = None,
                  status: NDArray[np.uint8] | None = None,
                  plans: Sequence[AnswerPlan] | None = None) -> list[list[bytes]]:
    """Every valid TPDO payload of each node (in its codec's order), from its codes ``(9, 3)``,
    taxel status and 0x2006: one numpy gather per mapping shape for all nodes mapped alike.
    ``codes`` ``(n, 9, 3)`` and ``status`` ``(n, 9)``: the nodes' own, already stacked.

    ``plans``: each node's :func:`answer_plan`, taken by the caller *before* the call, the
    one the payloads are then sent with. A master's SDO write remaps a PDO on canopen's
    thread without the device's lock, so the mapping may change at any moment: whoever
    sends the payloads must send them with the plan they were packed with, never look the
    plan up again. (The caller holds the nodes' locks so that codes and status agree.)
    """
    n = len(nodes)
    if not n:
        return []
    if codes is None:
        codes = np.stack([node.codes for node in nodes])
    if status is None:
        status = np.stack([node.faults.status for node in nodes])
    rows = np.empty((n, _ROW_BYTES), dtype=np.uint8)
    rows[:, :54] = codes.reshape(n, 27).astype("<u2", copy=False).view(np.uint8)
    rows[:, 54:63] = status
    rows[:, 63] = np.where(status.any(axis=1), REGISTER_FAULT, 0)  # FaultReporter's 0x1001
    rows[:, 64] = [node.answered for node in nodes]
    if plans is None:
        plans = [answer_plan(node) for node in nodes]
    layout = plans[0].layout
    if all(plan.layout is layout for plan in plans):  # the usual case: one shape
        groups = [list(range(n))]
    else:
        by_shape: dict[int, list[int]] = {}
        for i, plan in enumerate(plans):
            by_shape.setdefault(id(plan.layout), []).append(i)
        groups = list(by_shape.values())
    out: list[list[bytes]] = [[] for _ in nodes]
    for members in groups:
        layout = plans[members[0]].layout
        chosen = rows if len(members) == n else rows[members]
        blob = chosen[:, layout.gather].tobytes()
        total, spans = layout.total, layout.spans
        for m, i in enumerate(members):
            at = m * total
            out[i] = [blob[at + a:at + b] for a, b in spans]
    return out


class AnswerLayout:
    """A mapping shape: where each byte of each PDO comes from in a node's row. Codecs
    mapped alike share one (and so one gather for all their nodes)."""

    __slots__ = ("answered", "gather", "spans", "total")

    def __init__(self, codec: PdoCodec) -> None:
        gather: list[int] = []
        spans: list[tuple[int, int]] = []
        answered: list[tuple[int, int]] = []
        for p, layout in enumerate(codec.layouts):
            start = len(gather)
            for entry in layout.entries:
                if entry.index not in _ROW:
                    raise ConfigError("pdo mapping", f"0x{entry.index:04X} is not mappable on "
                                                     "a patch")
                base, width = _ROW[entry.index]
                if entry.index == ANSWERED:
                    answered.append((p, len(gather) - start))
                sub = 0 if entry.index in (0x1001, ANSWERED) else entry.subindex - 1
                gather += range(base + width * sub, base + width * sub + width)
            spans.append((start, len(gather)))
        self.gather = np.array(gather, dtype=np.intp)
        self.spans = tuple(spans)
        self.total = len(gather)
        self.answered = tuple(answered)
        """(PDO position, byte offset) of every mapped 0x2006."""


class AnswerPlan:
    """How a node answers with one codec: COB-IDs, the answer's order, what is sent when."""

    __slots__ = ("__weakref__", "cob_ids", "codec", "event", "every_sync", "layout", "order")

    def __init__(self, codec: PdoCodec, types: Sequence[int]) -> None:
        self.codec = codec
        key = tuple(lay.entries for lay in codec.layouts)
        layout = _SHAPES.get(key)
        if layout is None:
            layout = _SHAPES[key] = AnswerLayout(codec)
        self.layout = layout
        self.cob_ids: tuple[int, ...] = tuple(int(c) for c in codec.cob_ids.tolist())
        self.order = tuple(sorted(range(len(self.cob_ids)), key=self.cob_ids.__getitem__))
        """PDO positions in ascending COB-ID order: the order of an answer on the bus."""
        self.every_sync = all(t == 1 for t in types)
        """Every valid PDO goes out on every SYNC (type 1): the answer is all of them."""
        self.event = any(t in EVENT_DRIVEN for t in types)


_SHAPES: dict[tuple[Any, ...], AnswerLayout] = {}
_PLANS: weakref.WeakKeyDictionary[PdoCodec, AnswerPlan] = weakref.WeakKeyDictionary()


def answer_plan(node: PatchNode) -> AnswerPlan:
    """The node's plan for its current mapping (computed once per codec)."""
    codec = node.tpdo.codec
    plan = _PLANS.get(codec)
    if plan is None:
        codec, types = node.tpdo.mapping()
        plan = _PLANS.get(codec) or AnswerPlan(codec, types)
        _PLANS[codec] = plan
    return plan
