"""Samples out of PDOs: one node's mapped TPDOs of one sample, each once, joined.

A node publishes a sample as a set of TPDOs (7 classic frames for a patch or a force
node in 3-axis mode; one CAN FD frame can carry a whole sample). :class:`PdoAssembly`
holds one node's mapping (:class:`~canbus.pdo_codec.TpdoLayout` s, of any length up to
CAN FD's 64 bytes) and the sample being assembled: each frame's bytes go into a
preallocated buffer at its PDO's place; when the sample closes, one ``np.frombuffer``
with a structured dtype reads every mapped variable.

Where a sample begins. A classic PDO carries no cycle number, but a node sends the PDOs
of one sample together and in a fixed order, and the PDO with the lowest COB-ID comes
first in both orders a sender may use: TPDO number order (one transmit FIFO, the host's
force nodes) and ascending COB-ID (queued frames leave a CAN controller by arbitration);
it is TPDO 1 in the predefined connection set. That PDO, the *first*, begins a sample.
(Where a configuration gives TPDO 1 a higher COB-ID than another TPDO, the two orders
differ: a reader then takes the order its nodes use, ``PdoSampleReader.order``; the force
reader TPDO order, as the host's force nodes send. Read in the other order, two samples
would be joined.) So a sample closes:

- *complete* when every mapped PDO came once;
- *partial* when the next first PDO comes (the next sample began), or when a PDO it
  already holds comes again with other bytes (the next sample's first PDO was lost; the
  same bytes again right after are a CAN retransmission seen twice: ignored);
- *partial* when it was open for two sample periods (by bus time: nothing more will come);
  a sample that lacks its first PDO, for one period's 80 % (a sender holds one sample's
  PDOs together; this keeps two samples apart even when their first PDOs are both lost).

A sender that is held up mid-sample (a busy host thread) delays its PDOs; they still
join their own sample, never the next one. A partial sample carries the PDOs that came,
and says which. These are the rules for the samples of a node that follows no SYNC
window, a force node's (the host sends them as it decodes). A patch's answers to SYNC are
judged by the host's own rule (:mod:`canbus.answers`): the resistance reader assembles
them with :mod:`canbus.tools.patch_answers` (:meth:`PdoSampleReader._assembly`).

:class:`PdoSampleReader` is the ``can.Listener`` around assemblies of many nodes that the
force reader and the resistance reader share: the receive thread only appends
``(COB-ID, bytes, timestamp)`` of the frames it may need to a deque; :meth:`process`
(a thread of the reader's after :meth:`start`, or the caller) assembles. It follows SDO
transfers of its nodes (a master that remaps a PDO, or reads the mapping, is followed, as
the sniffer follows it) and the SYNC period.
"""

from __future__ import annotations

import itertools
import statistics
import threading
import time
from collections import deque
from collections.abc import Iterable, Sequence

import can
import canopen
import numpy as np

from canbus.pdo_codec import TpdoLayout
from canbus.tools.attribution import Attribution, KnownNode
from canbus.tools.pdo_assembly import JoinedPdos, PdoAssembly
from canbus.tools.pdo_dictionary import Dictionary
from canbus.tools.pdo_names import EdsChoice, NodeView
from canbus.tools.services import SdoDecoder

SYNC_COB_ID = 0x080
HEARTBEAT = 0x700
_SERVICES = frozenset((SYNC_COB_ID, *range(0x581, 0x680), *range(HEARTBEAT, HEARTBEAT + 0x80)))
DEFAULT_PERIOD_S = 0.01
"""The sample period assumed until SYNCs are seen: the host's default 100 Hz."""
_SYNC_INTERVALS = 8
_POLL_S = 0.02


Frame = tuple[int, bytes, float]
Closed = dict[int, tuple["PdoAssembly", list[JoinedPdos]]]
_RECENT = 1024
"""Unattributed frames held for a node that their sample may yet name (a few samples')."""


class PdoSampleReader(can.Listener):
    order = "cob-id"
    """How the nodes send one sample's PDOs when their TPDO 1 is not their lowest COB-ID:
    ``"cob-id"`` (queued frames leave by arbitration) or ``"tpdo"`` (one FIFO). Where TPDO 1
    has the lowest COB-ID (the predefined set, ascending custom COB-IDs) both agree."""

    """Samples of the TPDOs of ``node_ids`` (EDS ``eds``), handed to :meth:`on_samples`.

    A frame goes to a node's sample only when :mod:`canbus.tools.attribution` attributes
    its COB-ID to that node: ``known`` says what the caller's configuration knows (a node's
    TPDO COB-IDs, e.g. a host config's ``force_cob_ids``, or that it keeps its EDS
    defaults); the others are attributed by SDO transfers seen, or by their defaults once
    their heartbeat runs and their whole set of TPDOs has been seen together. Frames no
    node is known to send are counted in :attr:`unattributed`. ``period_s`` fixes the
    sample period the closing rules use (module docstring; default: the median of the
    last SYNC intervals seen, :data:`DEFAULT_PERIOD_S` before two SYNCs).
    """

    def __init__(self, node_ids: Iterable[int], eds: EdsChoice, *,
                 known: Iterable[KnownNode] = (), period_s: float | None = None) -> None:
        self.node_ids = tuple(sorted(set(node_ids)))
        self.dictionary = Dictionary(dict.fromkeys(self.node_ids, eds))
        self.attribution = Attribution(self.dictionary, known)
        self.fixed_period_s = period_s
        self.received = 0  # every frame the listener was handed
        self.frames = 0  # PDO frames of the nodes taken
        self.malformed = 0  # of which shorter than their mapping
        self.unattributed: dict[int, int] = {}  # COB-ID -> frames no node is known to send
        self.syncs = 0
        self.cycles = 0  # of which SYNCs that open a cycle (canbus.answers.counter_of_sync)
        self.sync_counter: int | None = None
        self.latest = -np.inf  # the newest bus timestamp processed
        self._sdo = SdoDecoder()
        self._sync_times: deque[float] = deque(maxlen=_SYNC_INTERVALS + 1)
        self._period_s = DEFAULT_PERIOD_S
        self._pending: deque[Frame] = deque()
        self._recent: deque[Frame] = deque(maxlen=_RECENT)
        self._lock = threading.Lock()
        self._assemblies: dict[int, PdoAssembly] = {}
        self._table: dict[int, PdoAssembly] = {}
        self._wanted: frozenset[int] = frozenset()
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()
        self._version = -1
        self._started = False
        for node in self.node_ids:
            view = self._view(node)
            self._assemblies[node] = self._assembly(node, view.tpdo_layouts(), view.od)
        self._follow_attribution()
        self._started = True  # from now on a node named mid-stream waits for its next sample

    # -- receive path -----------------------------------------------------------------

    def on_message_received(self, msg: can.Message) -> None:
        """Copies the frame if the reader may need it; nothing else."""
        self.received += 1
        if msg.arbitration_id in self._wanted and not msg.is_extended_id \
                and not msg.is_error_frame and not msg.is_remote_frame:
            self._pending.append((msg.arbitration_id, bytes(msg.data), msg.timestamp))

    # -- processing -------------------------------------------------------------------

    def start(self) -> None:
        """Process on a thread of the reader's, every 20 ms (a batch per node)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="pdo-samples", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """Stop the thread (if any) and process what is left, closing every sample still
        open (:meth:`finish`); safe to call again."""
        self._stopping.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()
        self.process()
        self.finish()

    def finish(self) -> None:
        """The bus or the recording ended: hand on the samples only its end closes (a
        patch's answer to the last SYNC, :mod:`canbus.tools.patch_answers`)."""
        with self._lock:
            for assembly in self._assemblies.values():
                raws = assembly.finish()
                if raws:
                    self.on_samples(assembly, raws)

    def _run(self) -> None:
        while not self._stopping.wait(_POLL_S):
            self.process()

    def period_s(self) -> float:
        """The sample period the closing rules use (the class docstring)."""
        if self.fixed_period_s is not None:
            return self.fixed_period_s
        return self._period_s

    def _on_sync(self, data: bytes, timestamp: float, closed: Closed) -> None:
        self.syncs += 1
        self.sync_counter = data[0] if data else None
        if len(data) <= 1:  # a SYNC, that opens a cycle (canbus.answers.counter_of_sync)
            self.cycles += 1
            for assembly in self._assemblies.values():
                raws = assembly.sync(data[0] if data else 0, timestamp)
                if raws:
                    closed.setdefault(id(assembly), (assembly, []))[1].extend(raws)
        times = self._sync_times
        times.append(timestamp)
        if len(times) >= 2:
            intervals = [b - a for a, b in itertools.pairwise(times)]
            self._period_s = statistics.median(intervals)

    def process(self, now: float | None = None) -> None:
        """Assemble every frame received so far, and close the samples open too long by
        the newest frame's time or ``now`` (bus time), whichever is later."""
        with self._lock:
            pending = self._pending
            closed: dict[int, tuple[PdoAssembly, list[JoinedPdos]]] = {}
            while pending:
                self._one(*pending.popleft(), closed)
            until = self.latest if now is None else max(self.latest, now)
            period = self.period_s()
            for assembly in self._assemblies.values():
                expired = assembly.expire(until, period)
                if expired is not None:
                    closed.setdefault(id(assembly), (assembly, []))[1].append(expired)
            for assembly, raws in closed.values():
                self.on_samples(assembly, raws)
                time.sleep(0)  # a thread waiting for the GIL (a bus, a host) goes first

    def _one(self, cob_id: int, data: bytes, timestamp: float, closed: Closed) -> None:
        """One frame copied by the receive path (lock held)."""
        if timestamp > self.latest:
            self.latest = timestamp
        if cob_id not in _SERVICES:
            self.attribution.frame(cob_id, timestamp, len(data))
        if self.dictionary.version != self._version:
            self._backfill(self._follow_attribution(), closed)
        assembly = self._table.get(cob_id)
        if assembly is not None and len(data) > 8 and \
                self._view(assembly.node_id).fd_frame(cob_id, len(data)):
            self._rebuild(assembly.node_id)  # a force node mapped for CAN FD in place
            assembly = self._table.get(cob_id)
        if assembly is not None:
            self._take(assembly, cob_id, data, timestamp, closed)
        elif cob_id == SYNC_COB_ID:
            self._on_sync(data, timestamp, closed)
            self.attribution.sync(timestamp)
        elif 0x581 <= cob_id <= 0x67F:
            self._sdo_frame(cob_id, data)
        elif HEARTBEAT <= cob_id <= HEARTBEAT + 0x7F:
            self.attribution.heartbeat(cob_id - HEARTBEAT,
                                       data[0] & 0x7F if len(data) == 1 else None, timestamp)
        else:
            self.unattributed[cob_id] = self.unattributed.get(cob_id, 0) + 1
            self._recent.append((cob_id, data, timestamp))

    def _take(self, assembly: PdoAssembly, cob_id: int, data: bytes, timestamp: float,
              closed: Closed) -> None:
        self.frames += 1
        before = assembly.malformed
        raws = assembly.take(cob_id, data, timestamp, self.period_s())
        if raws:
            closed.setdefault(id(assembly), (assembly, []))[1].extend(raws)
        self.malformed += assembly.malformed - before

    def _backfill(self, named: set[int], closed: Closed) -> None:
        """The frames held unattributed that nodes just named by their defaults sent since
        the first of the frames that named them (their sample, now known to be theirs)."""
        if not named:
            return
        keep: deque[Frame] = deque(maxlen=_RECENT)
        for cob_id, data, timestamp in self._recent:
            assembly = self._table.get(cob_id)
            since = self.attribution.named_at.get(assembly.node_id, np.inf) \
                if assembly is not None and assembly.node_id in named else np.inf
            if assembly is not None and timestamp >= since:
                left = self.unattributed[cob_id] - 1
                if left:
                    self.unattributed[cob_id] = left
                else:
                    del self.unattributed[cob_id]
                self._take(assembly, cob_id, data, timestamp, closed)
            else:
                keep.append((cob_id, data, timestamp))
        self._recent = keep

    def on_samples(self, assembly: PdoAssembly, raws: list[JoinedPdos]) -> None:
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
        self._assemblies[node_id] = self._assembly(node_id, view.tpdo_layouts(), view.od)
        self._follow_attribution()

    def _follow_attribution(self) -> set[int]:
        """Route to each node's assembly only the COB-IDs attributed to that node
        (:mod:`canbus.tools.attribution`); copy every COB-ID any of them may send on, its
        heartbeat and SDO, and SYNC, so that a node using its defaults can be confirmed.
        Returns the nodes named just now."""
        self._version = self.dictionary.version
        for node, assembly in list(self._assemblies.items()):
            view = self._view(node)
            layouts = tuple(view.tpdo_layouts())
            if layouts != assembly.layouts:  # a boot-up forgot a remap, CAN FD was adopted
                # (or a mapping was seen only in part)
                self._assemblies[node] = self._assembly(node, layouts, view.od)
        owners = self.attribution.table()
        before = {a.node_id for a in self._table.values()}
        self._table = {cob: a for a in self._assemblies.values() for cob in a.slots
                       if (owner := owners.get(cob)) is not None and owner.node == a.node_id}
        named = set()
        for assembly in {id(a): a for a in self._table.values()}.values():
            if self._started and assembly.node_id not in before:  # named mid-stream:
                assembly.await_first = True  # from its next sample on
                named.add(assembly.node_id)
        possible = {cob for a in self._assemblies.values() for cob in a.slots}
        services = {base + n for n in self._assemblies for base in (0x580, 0x600, HEARTBEAT)}
        self._wanted = frozenset(possible | set(self._table) | services | {SYNC_COB_ID})
        return named

    def _assembly(self, node_id: int, layouts: Sequence[TpdoLayout],
                  od: canopen.ObjectDictionary) -> PdoAssembly:
        """A new assembly of the node's samples (a force node's: PDOs joined by their
        order, :mod:`canbus.tools.pdo_assembly`)."""
        return PdoAssembly(node_id, layouts, od, order=self.order)

    def assembly(self, node_id: int) -> PdoAssembly:
        return self._assemblies[node_id]

    def feed(self, messages: Iterable[can.Message]) -> int:
        """Take ``messages`` (e.g. a recording's) as if received, process them and end there
        (:meth:`finish`); the count."""
        count = 0
        for msg in messages:
            self.on_message_received(msg)
            count += 1
            if count % 1024 == 0:
                self.process()
        self.process()
        self.finish()
        return count
