"""Force samples off any bus: the force nodes' TPDOs, read as any CANopen master reads them.

A force node (``eds/skin-forces.eds``) publishes one patch's forces: 0x2000, 27 INTEGER16
in mN (taxel*3 + axis + 1: Fx, Fy, Fz; 0x8000 = no value); 0x2005, the valid taxels
(bit k = taxel k) and bit 15 = the sample was complete; 0x2004, the per-taxel reason
code (``decoder.reasons``), where a master maps it (the default mapping has no room for
it). :class:`ForceReader` takes their TPDOs off a bus by the mapping of the EDS defaults
and of every mapping value a master writes or reads by SDO (as the sniffer does,
``canbus.tools.pdo_names``) or that the caller pins (a host config's ``force_cob_ids``),
and turns each node's TPDOs of one sample (:mod:`canbus.tools.pdo_samples`) into a
:class:`ForceSample`.

Which frames are a force node's: :mod:`canbus.tools.attribution` (the caller's
:class:`ForceNodeSpec`, SDO transfers on the bus, or the node's defaults once its
heartbeat and its whole set of PDOs are seen together); frames no node is known to send
are counted (:attr:`~canbus.tools.pdo_samples.PdoSampleReader.unattributed`), never read
as some node's forces.

The source patch of a force node: the caller's (a host config's ``force_node``), else its
0x2001 when an SDO transfer on the bus shows it, else node-ID - 64 (the host's default).

Receive path: :meth:`~canbus.tools.pdo_samples.PdoSampleReader.on_message_received` only
copies the bytes of the frames the reader may need; :meth:`process` (the reader's thread
after ``start()``, or the caller) assembles, counts (a
:class:`~canbus.tools.sample_tracker.SampleTracker`) and calls the ``on_sample``
callbacks; a view reads :meth:`ForceReader.snapshot`.

Which PDOs make one sample: :mod:`canbus.tools.pdo_samples` (the lowest-COB-ID PDO
begins a sample). A sample is complete when every mapped PDO came once and 0x2005 says
the host's sample was complete. A taxel is valid when its bit in
0x2005 is set and its three components came, none 0x8000. Where a force PDO did not come,
its taxels are invalid with reason MISSING (a taxel the mapping does not carry: invalid,
UNSPECIFIED). A CAN FD force node that sends the whole
sample in one frame (27 INTEGER16 + 0x2005 + a SYNC counter byte 0x2006, 57 bytes, at
TPDO 1's COB-ID) needs no change here but its mapping: the one PDO completes the sample,
and a mapped 0x2006 becomes :attr:`ForceSample.sync_counter`.

The contact summary (0x2008, :mod:`canbus.contact_record`), TPDO 8 by default, becomes
:attr:`ForceSample.contact`: whatever sub-indices the mapping carries, in SI units (None
where none is mapped, or where its PDO did not come).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canbus import contact_record
from canbus.contact_record import BusContact
from canbus.tools.attribution import KnownNode
from canbus.tools.pdo_assembly import JoinedPdos, PdoAssembly
from canbus.tools.pdo_names import EdsChoice
from canbus.tools.pdo_samples import PdoSampleReader
from canbus.tools.sample_tracker import PatchStatus, SampleTracker
from decoder.reasons import Reason
from skin.inputs import fields

FORCES, SOURCE, STATUS, VALID, SYNC_COUNTER = 0x2000, 0x2001, 0x2004, 0x2005, 0x2006
NO_VALUE = -0x8000
COMPLETE_BIT = 1 << 15
UNSPECIFIED = 0xFF
"""Reason of an invalid taxel whose reason is not on the bus (0x2004 not mapped)."""
FORCE_NODE_OFFSET = 64
FORCE_NODE_IDS = tuple(range(65, 128))
"""The node-IDs read when the caller names none: the host's default force nodes."""


@dataclass(frozen=True)
class ForceSample:
    """One force node's sample, as read off the bus."""

    patch: int  # the source patch's node-ID
    force_node: int
    timestamp: float  # bus time of the sample's last PDO
    force_N: NDArray[np.float64]  # (9, 3) Fx, Fy, Fz; 0 where invalid
    valid: NDArray[np.bool_]  # (9,)
    reason: NDArray[np.uint8]  # (9,) 0 OK, decoder.reasons code, UNSPECIFIED when unknown
    complete: bool  # every PDO came, and the host's sample was complete (0x2005 bit 15)
    pdos_missing: int  # force PDOs of this sample that did not come
    sync_counter: int | None = None  # 0x2006 where mapped (CAN FD)
    contact: BusContact | None = None  # 0x2008 where mapped (TPDO 8 by default) and it came


@dataclass(frozen=True)
class ForceNodeSpec:
    """What the caller knows about a force node: its patch, its TPDO COB-IDs (1..7), or
    that it keeps its EDS default COB-IDs (``known``; implied by ``cob_ids``). A node the
    caller only names is read by the attribution rule (:mod:`canbus.tools.attribution`):
    once its heartbeat and its whole default set of PDOs are seen."""

    node_id: int
    patch: int | None = None
    cob_ids: tuple[int, ...] | None = None
    known: bool = False


@dataclass(frozen=True)
class ReaderSnapshot:
    """The reader's counters and every patch's status at one time."""

    frames: int  # force PDOs taken
    malformed: int  # of which shorter than their mapping (not used)
    samples: int
    syncs: int
    patches: dict[int, PatchStatus]


class _Columns:
    """Where an assembly's variables go in a force sample."""

    def __init__(self, assembly: PdoAssembly) -> None:
        force_cols, force_at, status_cols, status_at = [], [], [], []
        self.valid: int | None = None
        self.counter: int | None = None
        self.contact: list[tuple[int, int]] = []  # (column, 0x2008 sub-index)
        for k, v in enumerate(assembly.variables):
            if v.index == FORCES and 1 <= v.subindex <= 27:
                force_cols.append(k)
                force_at.append(v.subindex - 1)
            elif v.index == STATUS and 1 <= v.subindex <= 9:
                status_cols.append(k)
                status_at.append(v.subindex - 1)
            elif v.index == VALID and v.subindex == 0:
                self.valid = k
            elif v.index == SYNC_COUNTER and v.subindex == 0:
                self.counter = k
            elif v.index == contact_record.CONTACT and 1 <= v.subindex <= contact_record.SUBS:
                self.contact.append((k, v.subindex))
        self.assembly = assembly
        self.force_cols = np.array(force_cols, dtype=np.intp)
        self.force_at = np.array(force_at, dtype=np.intp)
        self.status_cols = np.array(status_cols, dtype=np.intp)
        self.status_at = np.array(status_at, dtype=np.intp)
        self.pdos = len(assembly.layouts)
        mapped = np.zeros(27, dtype=bool)
        mapped[self.force_at] = True
        self.mapped = mapped.reshape(9, 3).all(axis=1)  # taxels with all 3 components mapped

    def samples(self, raws: list[JoinedPdos], patch: int) -> list[ForceSample]:
        """The force samples of ``raws`` (one node's), decoded at once."""
        n = len(raws)
        values = self.assembly.values(raws)
        arrived = self.assembly.arrived(raws)
        mN = np.full((n, 27), NO_VALUE, dtype=np.float64)
        came = np.zeros((n, 27), dtype=bool)
        mN[:, self.force_at] = values[:, self.force_cols]
        came[:, self.force_at] = arrived[:, self.force_cols]
        whole = came.reshape(n, 9, 3).all(axis=2)
        valid = (came & (mN != NO_VALUE)).reshape(n, 9, 3).all(axis=2)
        host_complete = np.zeros(n, dtype=bool)
        if self.valid is not None:
            got = arrived[:, self.valid]
            bits = np.where(got, values[:, self.valid], 0).astype(np.int64)
            valid &= (bits[:, None] >> np.arange(9) & 1).astype(bool) | ~got[:, None]
            host_complete = got & (bits & COMPLETE_BIT).astype(bool)
        reason = np.where(valid, 0, UNSPECIFIED).astype(np.uint8)
        if self.status_cols.size:
            known = arrived[:, self.status_cols]
            status = values[:, self.status_cols].astype(np.uint8)
            reason[:, self.status_at] = np.where(known & (status != 0), status,
                                                 reason[:, self.status_at])
            reason[valid] = 0
        reason[~whole & self.mapped] = Reason.MISSING
        force = np.where(valid[..., None], mN.reshape(n, 9, 3) / 1000.0, 0.0)
        counters: list[int | None] = [None] * n
        if self.counter is not None:
            counters = [int(v) if ok else None for v, ok in
                        zip(values[:, self.counter].tolist(),
                            arrived[:, self.counter].tolist(), strict=True)]
        complete = (host_complete & np.array([r.complete for r in raws], dtype=bool)).tolist()
        contacts = self._contacts(values, arrived)
        return [ForceSample(patch, raw.node_id, raw.timestamp, force[i], valid[i], reason[i],
                            complete[i], self.pdos - bin(raw.arrived).count("1"), counters[i],
                            contacts[i])
                for i, raw in enumerate(raws)]

    def _contacts(self, values: NDArray[np.float64], arrived: NDArray[np.bool_]
                  ) -> list[BusContact | None]:
        """Each sample's contact, from the 0x2008 sub-indices that came."""
        if not self.contact:
            return [None] * len(values)
        columns = [k for k, _ in self.contact]
        subs = [sub for _, sub in self.contact]
        out: list[BusContact | None] = []
        for row, came in zip(values[:, columns].astype(np.int64).tolist(),
                             arrived[:, columns].tolist(), strict=True):
            got = {sub: value for sub, value, ok in zip(subs, row, came, strict=True) if ok}
            out.append(contact_record.decode(got) if got else None)
        return out


class ForceReader(PdoSampleReader):
    """Force samples of the force nodes ``nodes`` (node-IDs or :class:`ForceNodeSpec`;
    default 65..127) on whatever bus it listens to (module docstring). ``eds``: their EDS
    (a path or a shipped name; e.g. a CAN FD force node's)."""

    order = "tpdo"  # the host's force nodes send a sample's PDOs in TPDO order

    def __init__(self, nodes: Iterable[int | ForceNodeSpec] | None = None, *,
                 eds: EdsChoice = "skin-forces", period_s: float | None = None,
                 tracker: SampleTracker | None = None) -> None:
        specs = [n if isinstance(n, ForceNodeSpec) else ForceNodeSpec(int(n))
                 for n in (FORCE_NODE_IDS if nodes is None else nodes)]
        self.patches = {s.node_id: s.patch if s.patch is not None
                        else s.node_id - FORCE_NODE_OFFSET for s in specs}
        self._pinned = {s.node_id for s in specs if s.patch is not None}
        self.tracker = tracker or SampleTracker()
        self.samples = 0
        self._callbacks: tuple[Callable[[ForceSample], None], ...] = ()
        self._columns: dict[int, _Columns] = {}
        super().__init__(self.patches, eds, period_s=period_s,
                         known=[KnownNode(s.node_id, eds, cob_ids=s.cob_ids) for s in specs
                                if s.known or s.cob_ids])
        for spec in specs:
            if spec.patch is not None:
                self.tracker.expect(spec.patch, spec.node_id)

    def on_sample(self, callback: Callable[[ForceSample], None]) -> None:
        """Call ``callback(sample)`` for every sample, on the processing thread."""
        self._callbacks = (*self._callbacks, callback)

    def on_samples(self, assembly: PdoAssembly, raws: list[JoinedPdos]) -> None:
        columns = self._columns.get(assembly.node_id)
        if columns is None or columns.assembly is not assembly:
            columns = self._columns[assembly.node_id] = _Columns(assembly)
        for sample in columns.samples(raws, self.patches[assembly.node_id]):
            self.samples += 1
            self.tracker.add(sample, partial=sample.pdos_missing > 0)
            for callback in self._callbacks:
                callback(sample)

    def on_observed(self, node_id: int, index: int, subindex: int, raw: bytes) -> None:
        if (index, subindex) == (SOURCE, 0) and raw and node_id not in self._pinned \
                and fields.is_node_id(raw[0]):
            self.patches[node_id] = raw[0]

    def snapshot(self, now: float | None = None) -> ReaderSnapshot:
        """Process what arrived, then the counters and every patch at bus time ``now``
        (default: the newest frame's)."""
        self.process(now)
        with self._lock:
            frames, malformed, samples, syncs = (self.frames, self.malformed, self.samples,
                                                 self.syncs)
        at = now if now is not None else (self.latest if np.isfinite(self.latest) else None)
        return ReaderSnapshot(frames, malformed, samples, syncs, self.tracker.status(at))
