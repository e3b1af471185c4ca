"""Samples out of PDOs: one node's mapped TPDOs of one sample, each once, joined.

A node publishes a sample as a set of TPDOs (7 classic frames for a patch or a force
node in 3-axis mode; one CAN FD frame can carry a whole sample). :class:`PdoAssembly`
holds one node's mapping (:class:`~canbus.pdo_codec.TpdoLayout` s, of any length up to
CAN FD's 64 bytes) and the sample being assembled: each frame's bytes go into a
preallocated buffer at its PDO's place; when the sample closes, one ``np.frombuffer``
with a structured dtype reads every mapped variable.

A sample closes *complete* when every mapped TPDO arrived once, and *partial* when one of
its PDOs comes again (the next sample began) or when it has been open longer than a
span (the caller's rule; the readers use 80 % of the SYNC period). So two samples are
never mixed, however frames are lost: a partial sample carries the PDOs that came, and
says which.

:class:`PdoSampleReader` is the ``can.Listener`` around assemblies of many nodes that the
force reader and the resistance reader share: the receive thread only appends
``(COB-ID, bytes, timestamp)`` of the frames it may need to a deque; :meth:`process`
(a thread of the reader's after :meth:`start`, or the caller) assembles. It follows SDO
transfers of its nodes (a master that remaps a PDO, or reads the mapping, is followed, as
the sniffer follows it) and the SYNC period.
"""

from __future__ import annotations

import statistics
import threading
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import can
import canopen
import numpy as np
from numpy.typing import NDArray

from canbus.pdo_codec import TpdoLayout, entry_dtype
from canbus.tools.pdo_names import Dictionary, EdsChoice, NodeView
from canbus.tools.services import SdoDecoder

SYNC_COB_ID = 0x080
DEFAULT_SPAN_S = 0.008
"""How long a sample may stay open before it closes partial, until SYNCs are seen: 80 %
of the 10 ms period of the host's default 100 Hz."""
SPAN_SHARE = 0.8
"""Of the median SYNC interval: a sample open longer is closed partial (CiA 301's
synchronous window, 0x1007, is typically this share of the period)."""
_SYNC_INTERVALS = 8
_POLL_S = 0.01


@dataclass(frozen=True)
class Variable:
    """A mapped object ``index:subindex`` and the PDO (bit in ``arrived``) that carries it."""

    index: int
    subindex: int
    pdo: int


@dataclass(frozen=True)
class RawSample:
    """One node's joined PDOs (read them with :meth:`PdoAssembly.values`)."""

    node_id: int
    timestamp: float  # bus time of the sample's last PDO
    payload: bytes  # the PDOs at their places in the assembly's buffer
    arrived: int  # bit p: PDO p (in ``PdoAssembly.layouts`` order) came
    complete: bool  # every mapped PDO came, once


class PdoAssembly:
    """One node's TPDO mapping and the sample being assembled (not thread-safe)."""

    def __init__(self, node_id: int, layouts: Sequence[TpdoLayout],
                 od: canopen.ObjectDictionary) -> None:
        self.node_id = node_id
        self.layouts = tuple(layouts)
        self.slots: dict[int, tuple[int, int, int]] = {}  # COB-ID -> (PDO bit, offset, size)
        formats: list[np.dtype[np.generic]] = []
        offsets: list[int] = []
        variables: list[Variable] = []
        taken: set[tuple[int, int]] = set()
        at = 0
        for bit, layout in enumerate(self.layouts):
            self.slots[layout.cob_id] = (bit, at, layout.size)
            offset = at
            for entry in layout.entries:
                key = (entry.index, entry.subindex)
                # index < 0x1000: CiA 301's dummy entries (a data type), padding only
                if entry.index >= 0x1000 and key not in taken:
                    taken.add(key)
                    formats.append(entry_dtype(entry, od))
                    offsets.append(offset)
                    variables.append(Variable(entry.index, entry.subindex, bit))
                offset += entry.bits // 8
            at += max(8, layout.size)
        self.variables = tuple(variables)
        self.size = max(at, 1)
        self.buffer = bytearray(self.size)
        by_dtype: dict[np.dtype[np.generic], list[int]] = {}
        for k, dtype in enumerate(formats):
            by_dtype.setdefault(dtype, []).append(k)
        self._groups = [(dtype, np.array(cols, dtype=np.intp),
                         np.array([offsets[k] + b for k in cols for b in range(dtype.itemsize)],
                                  dtype=np.intp))
                        for dtype, cols in by_dtype.items()]
        self._pdo = np.array([v.pdo for v in variables], dtype=np.int64)
        self.full = (1 << len(self.layouts)) - 1
        self.seen = 0
        self.first = 0.0
        self.last = 0.0
        self.malformed = 0

    def column(self, index: int, subindex: int) -> int | None:
        for k, v in enumerate(self.variables):
            if (v.index, v.subindex) == (index, subindex):
                return k
        return None

    def take(self, cob_id: int, data: bytes, timestamp: float,
             span_s: float) -> list[RawSample]:
        """One frame of PDO ``cob_id``: the samples it closes (none, one or two)."""
        bit, offset, size = self.slots[cob_id]
        out = []
        if self.seen and (self.seen >> bit & 1 or timestamp - self.first > span_s):
            out.append(self.close())
        if len(data) < size:
            self.malformed += 1  # not trusted: its PDO stays missing
            return out
        if not self.seen:
            self.first = timestamp
        self.buffer[offset:offset + size] = data[:size]
        self.seen |= 1 << bit
        self.last = timestamp
        if self.seen == self.full:
            out.append(self.close())
        return out

    def expire(self, now: float, span_s: float) -> RawSample | None:
        """The open sample, closed partial, if it has been open longer than ``span_s``."""
        if self.seen and now - self.first > span_s:
            return self.close()
        return None

    def close(self) -> RawSample:
        sample = RawSample(self.node_id, self.last, bytes(self.buffer), self.seen,
                           self.seen == self.full)
        self.seen = 0
        return sample

    def values(self, samples: Sequence[RawSample]) -> NDArray[np.float64]:
        """``(n, V)`` every mapped variable of ``n`` samples of this assembly, one numpy
        read; a PDO that did not come reads as the bytes left by the last one that did."""
        n = len(samples)
        raw = np.frombuffer(b"".join(s.payload for s in samples), dtype=np.uint8)
        raw = raw.reshape(n, self.size)
        out = np.empty((n, len(self.variables)), dtype=np.float64)
        for dtype, columns, byte_index in self._groups:
            out[:, columns] = np.ascontiguousarray(raw[:, byte_index]).view(dtype)
        return out

    def arrived(self, samples: Sequence[RawSample]) -> NDArray[np.bool_]:
        """``(n, V)`` whether each variable's PDO came."""
        bits = np.array([s.arrived for s in samples], dtype=np.int64)
        came: NDArray[np.bool_] = (bits[:, None] >> self._pdo[None, :] & 1).astype(bool)
        return came


Frame = tuple[int, bytes, float]


class PdoSampleReader(can.Listener):
    """Samples of the TPDOs of ``node_ids`` (EDS ``eds``), handed to :meth:`on_raw`.

    ``cob_ids`` pins a node's TPDO COB-IDs (TPDO 1, 2, ... in order; a master that set
    them without SDO, e.g. a host config's ``force_cob_ids``). ``max_span_s`` fixes the
    span after which an open sample closes partial (default: 80 % of the median SYNC
    interval seen, :data:`DEFAULT_SPAN_S` before two SYNCs).
    """

    def __init__(self, node_ids: Iterable[int], eds: EdsChoice, *,
                 cob_ids: dict[int, Sequence[int]] | None = None,
                 max_span_s: float | None = None) -> None:
        self.node_ids = tuple(sorted(set(node_ids)))
        self.dictionary = Dictionary(dict.fromkeys(self.node_ids, eds))
        self.max_span_s = max_span_s
        self.received = 0  # every frame the listener was handed
        self.frames = 0  # PDO frames of the nodes taken
        self.malformed = 0  # of which shorter than their mapping
        self.syncs = 0
        self.sync_counter: int | None = None
        self.latest = -np.inf  # the newest bus timestamp processed
        self._sdo = SdoDecoder()
        self._sync_times: deque[float] = deque(maxlen=_SYNC_INTERVALS + 1)
        self._span_s = DEFAULT_SPAN_S
        self._pending: deque[Frame] = deque()
        self._lock = threading.Lock()
        self._assemblies: dict[int, PdoAssembly] = {}
        self._table: dict[int, PdoAssembly] = {}
        self._wanted: frozenset[int] = frozenset()
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()
        for node in self.node_ids:
            view = self._view(node)
            for n, cob in enumerate((cob_ids or {}).get(node, ())):
                view.observe(0x1800 + n, 1, int(cob).to_bytes(4, "little"))
            self._rebuild(node)

    # -- receive path -----------------------------------------------------------------

    def on_message_received(self, msg: can.Message) -> None:
        """Copies the frame if the reader may need it; nothing else."""
        self.received += 1
        if msg.arbitration_id in self._wanted and not msg.is_extended_id \
                and not msg.is_error_frame:
            self._pending.append((msg.arbitration_id, bytes(msg.data), msg.timestamp))

    # -- processing -------------------------------------------------------------------

    def start(self) -> None:
        """Process on a thread of the reader's, every 10 ms."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="pdo-samples", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """Stop the thread (if any) and process what is left; safe to call again."""
        self._stopping.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()
        self.process()

    def _run(self) -> None:
        while not self._stopping.wait(_POLL_S):
            self.process()

    def span_s(self) -> float:
        """How long a sample may stay open (see the class docstring)."""
        if self.max_span_s is not None:
            return self.max_span_s
        return self._span_s

    def _on_sync(self, data: bytes, timestamp: float) -> None:
        self.syncs += 1
        self.sync_counter = data[0] if data else None
        times = self._sync_times
        times.append(timestamp)
        if len(times) >= 2:
            intervals = [b - a for a, b in zip(times, list(times)[1:], strict=False)]
            self._span_s = SPAN_SHARE * statistics.median(intervals)

    def process(self, now: float | None = None) -> None:
        """Assemble every frame received so far; with ``now`` (bus time), also close the
        samples that have been open longer than the span by then."""
        with self._lock:
            pending = self._pending
            sdo_low, sdo_high = 0x581, 0x67F
            span = self.span_s()
            closed: dict[int, tuple[PdoAssembly, list[RawSample]]] = {}
            while pending:
                cob_id, data, timestamp = pending.popleft()
                if timestamp > self.latest:
                    self.latest = timestamp
                assembly = self._table.get(cob_id)
                if assembly is not None:
                    self.frames += 1
                    before = assembly.malformed
                    raws = assembly.take(cob_id, data, timestamp, span)
                    if raws:
                        closed.setdefault(id(assembly), (assembly, []))[1].extend(raws)
                    self.malformed += assembly.malformed - before
                elif cob_id == SYNC_COB_ID:
                    self._on_sync(data, timestamp)
                    span = self.span_s()
                elif sdo_low <= cob_id <= sdo_high:
                    self._sdo_frame(cob_id, data)
            until = self.latest if now is None else max(self.latest, now)
            span = self.span_s()
            for assembly in self._assemblies.values():
                expired = assembly.expire(until, span)
                if expired is not None:
                    closed.setdefault(id(assembly), (assembly, []))[1].append(expired)
            for assembly, raws in closed.values():
                self.on_samples(assembly, raws)

    def on_samples(self, assembly: PdoAssembly, raws: list[RawSample]) -> None:
        """Samples of one node that closed, in order (called with the reader's lock
        held, once per node and :meth:`process`); subclasses interpret them."""

    # -- mapping ----------------------------------------------------------------------

    def _view(self, node_id: int) -> NodeView:
        view = self.dictionary.view(node_id)
        assert view is not None  # node-IDs were checked (1..127) by Dictionary's assignments
        return view

    def _sdo_frame(self, cob_id: int, data: bytes) -> None:
        node, request = cob_id & 0x7F, cob_id >= 0x600
        if node not in self._assemblies:
            return
        view = self._view(node)
        _, observed = self._sdo.decode(node, request, data, view)
        if observed is None:
            return
        self.on_observed(node, *observed)
        version = self.dictionary.version
        self.dictionary.observe(node, *observed)
        if self.dictionary.version != version:
            self._rebuild(node)

    def on_observed(self, node_id: int, index: int, subindex: int, raw: bytes) -> None:
        """An object value an SDO transfer of node ``node_id`` carried (lock held)."""

    def _rebuild(self, node_id: int) -> None:
        """The node's assembly from its current mapping; its open sample is dropped (a
        mapping change mid-sample: the node's PDOs before it are of the old one)."""
        view = self._view(node_id)
        self._assemblies[node_id] = PdoAssembly(node_id, view.tpdo_layouts(), view.od)
        table = {cob: a for a in self._assemblies.values() for cob in a.slots}
        self._table = table
        sdo = {base + n for n in self._assemblies for base in (0x580, 0x600)}
        self._wanted = frozenset(table) | sdo | {SYNC_COB_ID}

    def assembly(self, node_id: int) -> PdoAssembly:
        return self._assemblies[node_id]

    def feed(self, messages: Iterable[can.Message]) -> int:
        """Take ``messages`` (e.g. a recording's) as if received and process them; the count."""
        count = 0
        for msg in messages:
            self.on_message_received(msg)
            count += 1
            if count % 1024 == 0:
                self.process()
        self.process()
        return count
