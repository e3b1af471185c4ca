"""Bus statistics for the sniffer: per COB-ID counts, rate and Δt, bus load, anomalies.

:class:`Sniffer` is a ``can.Listener``. Its receive path does little per frame: a table
lookup for the service (``canbus.tools.services.route``), a few counters under a short lock,
and the word decoding only for the rare management frames (NMT, EMCY, SDO, TIME, LSS,
heartbeat state changes), which become events. PDO values are decoded only when a view
asks for them, from the last frame of each COB-ID. A view reads :meth:`Sniffer.snapshot`
(an immutable copy); it never holds up the receive path for longer than that copy.

Bus load counts bits as ``skin plan`` does (``canbus.busload``): 47 + 8n bits per classic
frame with an 11-bit id without stuffing, plus floor((34 + 8n - 1) / 4) stuff bits in the
worst case; a 29-bit id adds 20 bits to the stuffed part (SRR, IDE and 18 more id bits);
a remote frame carries no data bits; error frames are not counted.

Anomalies:
- missed SYNC cycles: gaps in the SYNC counter; without a counter, intervals longer
  than 1.5 times the median of the last 8 are counted as that many periods;
- incomplete samples: a patch's answers judged as the host judges them
  (:mod:`canbus.answers`, through :class:`~canbus.tools.answer_reader.AnswerReader`): one
  sample per SYNC cycle from the first SYNC after its PDOs are known (their COB-IDs
  attributed to it), complete when every TPDO of one answer came once and in order
  before the next SYNC (the frame just taken again with the same bytes, a CAN
  retransmission, changes nothing); ``on_answer`` is handed each. Any other node (a force
  node, a node without a shipped EDS) is judged at each SYNC by the PDOs it sends in other
  cycles: incomplete when one of them did not come in the cycle, or one came twice (a
  node that sent nothing in the cycle is not judged, nor frames before the first SYNC);
- heartbeat gaps: a node's heartbeat interval over 1.5 times the median of its last 8;
- unknown COB-IDs: frames outside the predefined connection set and 29-bit ids;
- unattributed PDOs: PDOs no node is known to send (``canbus.tools.attribution``: a
  config, an SDO transfer, or a node confirmed on its default COB-IDs); they are shown as
  bytes, never decoded as some node's;
- error frames.

Own frames: a sniffer counts what crosses the bus. Given the ``ReceiveFilter`` of its bus
(``own=``, ``canbus.rxfilter``), it leaves out the echoes of frames other parts of its own
process sent through that same bus object (on udp_multicast, which hands a process its own
frames back; counted in :attr:`Sniffer.own_frames`), so its counts are the same on every
interface: python-can's virtual, timed and socketcan buses do not return a bus's own frames
either. ``skin sniff`` runs in a process of its own and sends nothing: it counts every frame
of the bus once.
"""

from __future__ import annotations

import statistics
import threading
import time
from collections import deque
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass

import can

from canbus.answers import PatchAnswer
from canbus.frametime import frame_bit_bounds
from canbus.identity import PATCH_PRODUCT
from canbus.rxfilter import ReceiveFilter
from canbus.tools.answer_reader import Answer, AnswerReader
from canbus.tools.services import Decoded, Route, Service, ServiceDecoder, route
from canbus.tools.snapshot import Anomalies, CobRow, Snapshot

_MANAGEMENT = frozenset((Service.NMT, Service.EMCY, Service.SDO, Service.TIME, Service.LSS))
_PDO_SHAPED = frozenset((Service.PDO, Service.UNKNOWN))
_WINDOW = 8


class _Period:
    """Judges an interval against the median of the last few."""

    def __init__(self) -> None:
        self.recent: deque[float] = deque(maxlen=_WINDOW)

    def periods_missed(self, interval: float) -> int:
        """0 for a normal interval, else how many periods it skipped (at least 1)."""
        missed = 0
        if self.recent:
            typical = statistics.median(self.recent)
            if typical > 0 and interval > 1.5 * typical:
                missed = max(1, round(interval / typical) - 1)
        self.recent.append(interval)
        return missed


@dataclass(slots=True)
class _Cob:
    route: Route
    known: bool
    version: int
    count: int = 0
    first: float = 0.0
    last: float = 0.0
    dt_last: float = 0.0
    dt_min: float = float("inf")
    dt_max: float = 0.0
    msg: can.Message | None = None
    text: str = ""


class FrameFilter:
    """Which frames a view shows: by node-ID and by service (empty: all)."""

    def __init__(self, nodes: Collection[int] = (), services: Collection[str] = ()) -> None:
        self.nodes = frozenset(nodes)
        self.services = frozenset(Service(s) for s in services)

    def __call__(self, where: Route) -> bool:
        if self.nodes and where.node not in self.nodes:
            return False
        return not self.services or where.service in self.services


class Sniffer(can.Listener):
    """Counts, times and judges every frame; decodes management frames into events."""

    def __init__(self, decoder: ServiceDecoder | None = None, *, bitrate: int = 1_000_000,
                 data_bitrate: int | None = None, events: int = 200,
                 on_frame: Callable[[can.Message, Route, Decoded | None], None] | None = None,
                 own: ReceiveFilter | None = None,
                 on_answer: Callable[[Answer], None] | None = None,
                 answer_orders: Mapping[int, str] | None = None) -> None:
        """``on_answer``: called with each patch answer judged (module docstring), on the
        receive thread with the sniffer's lock held; ``answer_orders``: node-ID -> the order
        a patch sends an answer's TPDOs in (a host config's ``answer_order``; default
        ascending COB-ID)."""
        self.decoder = decoder or ServiceDecoder()
        self.own = own
        self.own_frames = 0
        """Echoes of this process's own frames, left out of every count."""
        self.bitrate = bitrate
        self.data_bitrate = data_bitrate
        self.on_frame = on_frame
        self._lock = threading.Lock()
        self._cobs: dict[tuple[int, bool, bool], _Cob] = {}
        self._bits: dict[tuple[int, bool, bool, bool, bool], tuple[float, float]] = {}
        self._events: deque[Decoded] = deque(maxlen=events)
        self._by_service: dict[str, int] = {}
        self.frames = 0
        self._first: float | None = None
        self._last: float | None = None
        self._best = self._worst = 0.0
        self._missed_sync = self._incomplete = self._complete = 0
        self._gaps = self._unknown = self._errors = 0
        self._unknown_ids: set[int] = set()
        self._unattributed = 0
        self._unattributed_ids: set[int] = set()
        self._sync_counter: int | None = None
        self._sync_top = 0
        self._sync_period = _Period()
        self._last_sync: float | None = None
        self._cycle: dict[int, set[int]] | None = None
        self._duplicates: set[int] = set()
        self._expected: dict[int, set[int]] = {}
        self._heartbeats: dict[int, tuple[float | None, _Period, int | None]] = {}
        self._states: dict[int | None, int] = {}
        self.on_answer = on_answer
        self.answer_orders = dict(answer_orders or {})
        self._answers = AnswerReader(self._answered)
        self._answers_version = -1  # the dictionary's, when the patches followed were chosen

    def on_message_received(self, msg: can.Message) -> None:
        if self.own is not None and self.own.is_own(msg):
            self.own_frames += 1
            return
        attribution = self.decoder.attribution
        if not msg.is_extended_id and not msg.is_error_frame and not msg.is_remote_frame \
                and route(msg).service in _PDO_SHAPED:
            attribution.frame(msg.arbitration_id, msg.timestamp, len(msg.data))
        where = self.decoder.route(msg)
        decoded = None
        service = where.service
        if service in _MANAGEMENT or (service is Service.HEARTBEAT and self._new_state(
                where.node, msg)):
            decoded = self.decoder.decode(msg, where)
        with self._lock:
            self._count(msg, where, decoded)
        if self.on_frame is not None:
            self.on_frame(msg, where, decoded)

    def _new_state(self, node: int | None, msg: can.Message) -> bool:
        """A heartbeat is an event when it is a boot-up or its state is new (receive thread)."""
        state = msg.data[0] if len(msg.data) == 1 else -1
        changed = state == 0 or self._states.get(node) != state
        self._states[node] = state
        return changed

    def _count(self, msg: can.Message, where: Route, decoded: Decoded | None) -> None:
        """Every counter one frame moves (lock held)."""
        self.frames += 1
        if self._first is None:
            self._first = msg.timestamp
        self._last = msg.timestamp
        service = where.service
        self._by_service[service] = self._by_service.get(service, 0) + 1
        cob = self._cob(msg, where)
        if decoded is not None:
            cob.text = decoded.text
            self._events.append(decoded)
        if not msg.is_error_frame:
            self._add_bits(msg)
        if not cob.known and service is Service.PDO:
            self._unattributed += 1
            self._unattributed_ids.add(msg.arbitration_id)
        elif not cob.known:
            self._unknown += 1
            self._unknown_ids.add(msg.arbitration_id)
        if service is Service.SYNC:
            self._follow_patches()  # a patch known by now is judged from this SYNC on
        self._answers.take(msg)
        if service is Service.PDO and self._cycle is not None and where.node is not None:
            if not self._is_patch(where.node):
                seen = self._cycle.setdefault(where.node, set())
                if msg.arbitration_id in seen:
                    self._duplicates.add(where.node)
                seen.add(msg.arbitration_id)
        elif service is Service.SYNC:
            self._on_sync(msg)
            self.decoder.attribution.sync(msg.timestamp)
        elif service is Service.HEARTBEAT and where.node is not None:
            self._on_heartbeat(where.node, msg)
            self.decoder.attribution.heartbeat(
                where.node, msg.data[0] & 0x7F if len(msg.data) == 1 else None, msg.timestamp)
        elif service is Service.ERROR:
            self._errors += 1

    def _cob(self, msg: can.Message, where: Route) -> _Cob:
        """The COB-ID's entry with this frame counted and timed."""
        key = (msg.arbitration_id, msg.is_extended_id, msg.is_error_frame)
        cob = self._cobs.get(key)
        version = self.decoder.dictionary.version
        if cob is None:
            cob = self._cobs[key] = _Cob(where, self._known(msg, where), version,
                                          first=msg.timestamp)
        elif cob.version != version:  # an EDS, a mapping or an owner changed: known again?
            cob.route, cob.known, cob.version = where, self._known(msg, where), version
        if cob.count:
            interval = msg.timestamp - cob.last
            cob.dt_last = interval
            cob.dt_min = min(cob.dt_min, interval)
            cob.dt_max = max(cob.dt_max, interval)
        cob.count += 1
        cob.last = msg.timestamp
        cob.msg = msg
        return cob

    def _add_bits(self, msg: can.Message) -> None:
        key = (len(msg.data), msg.is_extended_id, msg.is_fd, msg.bitrate_switch,
               msg.is_remote_frame)
        bits = self._bits.get(key)
        if bits is None:
            bits = self._bits[key] = frame_bit_bounds(msg, self.bitrate, self.data_bitrate)
        self._best += bits[0]
        self._worst += bits[1]

    def _known(self, msg: can.Message, where: Route) -> bool:
        if where.service is Service.UNKNOWN:
            return False
        if where.service is Service.PDO:
            return where.node is not None  # attributed (canbus.tools.attribution)
        return True

    def _on_sync(self, msg: can.Message) -> None:
        if self._cycle is not None:
            for node, seen in self._cycle.items():
                expected = self._expected.setdefault(node, set())
                if expected - seen or node in self._duplicates:
                    self._incomplete += 1
                else:
                    self._complete += 1
                expected |= seen
        self._cycle, self._duplicates = {}, set()
        if len(msg.data) == 1:
            counter = msg.data[0]
            if self._sync_counter is not None:
                gap = counter - self._sync_counter - 1
                self._missed_sync += gap if gap >= 0 else gap + self._sync_top
            self._sync_counter, self._sync_top = counter, max(self._sync_top, counter)
        elif self._last_sync is not None:
            self._missed_sync += self._sync_period.periods_missed(msg.timestamp - self._last_sync)
        self._last_sync = msg.timestamp

    def _is_patch(self, node: int) -> bool:
        view = self.decoder.dictionary.view(node)
        return view is not None and view.product == PATCH_PRODUCT

    def _follow_patches(self) -> None:
        """Judge, from the cycle the SYNC being taken opens, the answers of every patch
        whose TPDOs are all known to be its own (lock held)."""
        dictionary = self.decoder.dictionary
        if dictionary.version == self._answers_version:
            return
        owners = self.decoder.attribution.table()
        patches = []
        for view in dictionary.views():
            layouts = view.tpdo_layouts()
            if view.product == PATCH_PRODUCT and layouts and all(
                    (owner := owners.get(layout.cob_id)) is not None
                    and owner.node == view.node_id and owner.kind == "TPDO"
                    for layout in layouts):
                patches.append(PatchAnswer(view.node_id, layouts, answer_order=self.answer_orders
                                           .get(view.node_id, "cob-id")))
        self._answers.follow(patches)
        self._answers_version = dictionary.version

    def _answered(self, answer: Answer) -> None:
        """A patch's sample of a cycle, judged (lock held)."""
        if answer.complete:
            self._complete += 1
        else:
            self._incomplete += 1
        if self.on_answer is not None:
            self.on_answer(answer)

    def _on_heartbeat(self, node: int, msg: can.Message) -> None:
        view = self.decoder.dictionary.view(node)
        period_ms = view.heartbeat_ms if view is not None else None
        last, period, was_ms = self._heartbeats.get(node, (None, _Period(), period_ms))
        if was_ms != period_ms:  # 0x1017 was written or read: a new period, judge afresh
            period = _Period()
        elif last is not None and period.periods_missed(msg.timestamp - last):
            self._gaps += 1
        if msg.data[:1] == b"\0":  # boot-up: the period starts over
            self._heartbeats[node] = (None, _Period(), period_ms)
        else:
            self._heartbeats[node] = (msg.timestamp, period, period_ms)

    def snapshot(self) -> Snapshot:
        with self._lock:
            rows = tuple(CobRow(cob_id, ext, c.route.service, c.route.node, c.route.label,
                                c.count, c.first, c.last, c.dt_last, c.dt_min, c.dt_max,
                                c.known, c.msg, c.text)
                         for (cob_id, ext, _), c in sorted(self._cobs.items()))
            anomalies = Anomalies(self._missed_sync, self._incomplete, self._complete,
                                  self._gaps, self._unknown, tuple(sorted(self._unknown_ids)),
                                  self._errors, self._unattributed,
                                  tuple(sorted(self._unattributed_ids)))
            return Snapshot(time.monotonic(), self.frames, self._first, self._last, self._best,
                            self._worst, self.bitrate, dict(self._by_service), rows, anomalies,
                            tuple(self._events), dict(self.decoder.states))

