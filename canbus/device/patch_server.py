"""Many patch nodes on one or several buses, fed by one signal source, at the cost of the bus.

A sample is taken in one place: with ``event_rate_hz`` a thread reads the source at that
rate (the source's own clock, which also serves event-driven TPDOs) and a SYNC picks up the
latest sample; without it every SYNC reads the next sample (one bus only). Taking a sample
does all the work there is per sample, for every patch at once: one read of the source (one
vectorised simulator step), one code and status conversion, one numpy gather per mapping
shape for all the TPDO payloads (:func:`pack_payloads`), and the ``can.Message`` of every
TPDO. A SYNC then only picks up those messages of its bus's OPERATIONAL nodes and hands them
to the bus's ``send``: each patch's TPDOs in ascending COB-ID order (as a CAN controller
sends its queued frames), the patches in node-ID order, as fast as the interface takes them.
On a bus whose ``send`` waits for room (the timed bus's transmit queue), the wire, not the
server, sets the pace. A SYNC that finds a node remapped since the sample was packed packs
that node anew; a mapping other than "every PDO on every SYNC" (types 0, 2..240), and 0x2006
(the answered SYNC's counter, CAN FD), take the general path.

canopen's machinery (the LocalNode object store, SDO server, NMT, heartbeat, EMCY) stays for
the management plane; TPDOs never pass through it. On a bus that hands a process its own
frames back (udp_multicast), the nodes' own COB-IDs are claimed (``canbus.rxfilter``): the
kernel drops their echoes, or, where it cannot, a gate in front of canopen's listener does.
``accept_only_consumed``: the server owns its buses and, as a device's CAN controller's
acceptance filter does, lets through only what its nodes consume (NMT, SYNC, SDO requests to
them): another host's force PDOs never wake it (in the kernel on udp_multicast).
"""

from __future__ import annotations

import functools
import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from typing import NamedTuple

import can
import canopen
import numpy as np

from canbus import codes
from canbus.busload import spread
from canbus.device.lss_slave import LSS_MASTER
from canbus.device.nmt_slave import OPERATIONAL
from canbus.device.nv_store import NvStore
from canbus.device.patch_node import (
    AnswerPlan,
    PatchNode,
    answer_plan,
    locked,
    pack_payloads,
)
from canbus.device.server_bus import (
    SYNC_COB_ID,
    ServerBus,
    SyncCallback,
    answer_order,
    claim_own_frames,
    follow_sync,
    patch_identity,
    release_own_frames,
)
from canbus.device.source import ResistanceSource
from canbus.identity import Identity
from canbus.txmessage import TxMessage
from canbus.worker import Worker
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.inputs.fields import UNCONFIGURED

logger = logging.getLogger(__name__)



class _Prepared(NamedTuple):
    """A node's TPDOs for one sample: the plan they were packed with, each payload (codec
    order) and the messages of the whole answer (COB-ID order)."""

    plan: AnswerPlan
    payloads: list[bytes]
    messages: list[can.Message]


class PatchServer:
    """The source's patches as :class:`PatchNode` s on ``network`` (or spread in node order
    over several networks, as ``skin plan --buses`` spreads them); a context manager."""

    def __init__(self, network: canopen.Network | Sequence[canopen.Network],
                 source: ResistanceSource, *, mode: str | None = None,
                 constants: SensorConstants = DEFAULT_CONSTANTS,
                 event_rate_hz: float = 0.0, accept_only_consumed: bool = False,
                 serials: Sequence[int] | None = None, unconfigured: bool = False,
                 nv: Callable[[Identity], NvStore] | None = None) -> None:
        networks = [network] if isinstance(network, canopen.Network) else list(network)
        if not networks:
            raise ValueError("no network to serve the patches on")
        if len(networks) > 1 and event_rate_hz <= 0:
            raise ValueError("patches on several buses need event_rate_hz > 0: the source "
                             "runs on its own clock, and each bus's SYNC picks up its sample")
        if len(networks) > len(source.node_ids):
            raise ValueError(f"{len(networks)} buses for {len(source.node_ids)} patches")
        self.networks = networks
        self.network = networks[0]
        self.source = source
        mode = mode or ("z" if source.pillars == 1 else "xyz")
        serials = list(source.node_ids) if serials is None else list(serials)
        if len(serials) != len(source.node_ids):
            raise ValueError(f"{len(serials)} serial numbers for {len(source.node_ids)} patches")
        self.nodes = [PatchNode(UNCONFIGURED if unconfigured else n, mode=mode,
                                constants=constants, serial=serial,
                                nv=None if nv is None else nv(patch_identity(serial)))
                      for n, serial in zip(source.node_ids, serials, strict=True)]
        self._codes = np.stack([node.codes for node in self.nodes])
        for node, node_codes in zip(self.nodes, self._codes, strict=True):
            node.codes = node_codes  # a view: one copy updates every node's codes
        self._lsb = constants.resistance_lsb_ohm
        self._no_fault = np.zeros((len(self.nodes), 9), dtype=np.uint8)
        self._faulty = False  # some node's status is not all zero
        # The source's patches in its order (the nodes' node-IDs may change by LSS).
        self.buses = [ServerBus(net, [self.nodes[k] for k in group])
                      for net, group in zip(networks, spread(list(range(len(self.nodes))),
                                                             len(networks)), strict=True)]
        for bus in self.buses:
            bus.nodes.sort(key=answer_order)
        self.sync_count = 0
        self.samples = 0
        self._prepared: dict[PatchNode, _Prepared] = {}
        self._lock = threading.Lock()
        self._quiet = threading.Condition()
        self._event_rate_hz = event_rate_hz
        self._accept_only_consumed = accept_only_consumed
        self._sampler = Worker(self._sample_loop, "patch-samples")
        self.failure: Exception | None = None
        """Why the patches stopped taking samples (None: they take them): from then on no
        SYNC is answered, so no master decodes a frozen sample as a live one."""
        self.failed = threading.Event()

    @property
    def frames_sent(self) -> int:
        return sum(bus.frames_sent for bus in self.buses)

    def start(self) -> None:
        self._tick()  # nodes hold a real sample before anyone can read them
        for bus in self.buses:
            # SYNC is followed before any node boots: a master that starts on a boot-up
            # finds every SYNC it sends counted (each SYNC reads its own simulator step)
            bus.on_sync = self._sync_handler(bus)
            follow_sync(bus)
            for node in bus.nodes:
                node.on_node_id_changed = self._node_id_changed
                node.on_cob_ids_changed = functools.partial(self._cob_ids_changed, bus)
                node.attach(bus.network)
            self._claim(bus)
        if self._event_rate_hz > 0:
            self._sampler.start()

    def stop(self) -> None:
        self._sampler.stop()
        for bus in self.buses:
            if bus.on_sync is not None:
                for cob_id in bus.sync_subscribed:
                    bus.network.unsubscribe(cob_id, bus.on_sync)
                bus.sync_subscribed = set()
                bus.on_sync = None
            for node in bus.nodes:
                node.detach()
                node.on_node_id_changed = node.on_cob_ids_changed = None
            self._release(bus)

    def __enter__(self) -> PatchServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """One SYNC on the first bus: its nodes' synchronous TPDOs."""
        self._answer(self.buses[0], data[0] if data else 0, timestamp, can_id)

    @property
    def late_answers(self) -> int:
        """Answers, on every bus, that ended after the next SYNC was due."""
        return sum(bus.late for bus in self.buses)

    def answer_ms(self) -> tuple[float, float]:
        """p50 and p99 over every bus of the time from a SYNC's receive stamp (the bus's
        timestamp) to the return of its answer's last ``send``, in ms (NaN: no answer)."""
        times = np.fromiter((t for bus in self.buses for t in bus.answer_s), dtype=np.float64)
        if not times.size:
            return math.nan, math.nan
        p50, p99 = np.percentile(1e3 * times, [50, 99])
        return float(p50), float(p99)

    def answer(self, bus: int = 0) -> list[can.Message]:
        """The messages a SYNC on bus ``bus`` would send now, of nodes that send every valid
        TPDO on every SYNC (the default mapping), in the order it would send them."""
        prepared = self._prepared
        return [msg for node in self.buses[bus].nodes
                if node.nmt.state == OPERATIONAL and node in prepared
                and prepared[node].plan.every_sync
                for msg in prepared[node].messages]

    def _sync_handler(self, bus: ServerBus) -> SyncCallback:
        def on_sync(can_id: int, data: bytearray, timestamp: float) -> None:
            self._answer(bus, data[0] if data else 0, timestamp, can_id)
        return on_sync

    # --- node-IDs and SYNC COB-IDs that change (LSS, 0x1005) ----------------------------

    def _node_id_changed(self, node: object) -> None:
        """A node took a new node-ID: answers keep node-ID order. (On the network's thread,
        the node's lock held: no lock of the server's here, the sample thread takes them
        the other way round; the new list replaces the old one whole.)"""
        for bus in self.buses:
            if node in bus.nodes:
                bus.nodes = sorted(bus.nodes, key=answer_order)

    def _cob_ids_changed(self, bus: ServerBus) -> None:
        """A node's node-ID, SYNC or other COB-IDs changed: SYNCs to follow, own COB-IDs
        and the acceptance list anew."""
        if bus.on_sync is None:
            return
        follow_sync(bus)
        if bus.own is not None and self._accept_only_consumed:
            bus.own.accept_only(self.consumed_cob_ids(self.buses.index(bus)))
        self._claim(bus)


    # --- samples ----------------------------------------------------------------------

    def _sample_loop(self) -> None:
        period = 1.0 / self._event_rate_hz
        deadline = time.monotonic()
        stopping = self._sampler.stopping
        while not stopping.is_set():
            deadline += period
            late = time.monotonic() - deadline
            if late > period:  # a stall (a busy machine): carry on from now, do not catch up
                deadline += late
            stopping.wait(max(0.0, deadline - time.monotonic()))
            if stopping.is_set():
                break
            self._wait_quiet(deadline, period)
            try:
                self._tick()
            except Exception as err:
                self._fail(err)
                return
            self._send_events(time.monotonic())

    def _fail(self, err: Exception) -> None:
        """The source failed: every patch halts (EMCY 0x6100) and answers no more SYNCs."""
        with self._lock:
            if self.failure is not None:
                return
            self.failure = err
        logger.error("patch server: the source failed, the patches answer no more SYNCs: "
                     "%s: %s", type(err).__name__, err)
        for node in self.nodes:
            node.halt()
        self.failed.set()

    def _wait_quiet(self, since: float, period: float) -> None:
        """While SYNCs come, wait (at most a period) until every bus that has them answered
        after ``since``: a sample is taken in the quiet right after the answers, never
        during one, where an answer's sends would wait for the GIL the step holds."""
        def answered() -> bool:
            now = time.monotonic()
            return all(bus.answered_at >= since for bus in self.buses
                       if now - bus.last_sync < 2 * period)

        with self._quiet:
            self._quiet.wait_for(answered, timeout=period)

    def _tick(self) -> None:
        """The next sample, read outside the lock (the SYNCs go on meanwhile)."""
        sample = self._read()
        with self._lock:
            remapped = self._take(sample)
        if remapped:
            for bus in self.buses:
                self._claim(bus)

    def _read(self) -> np.ndarray:
        sample = np.asarray(self.source.read(), dtype=np.float64)
        if len(sample) != len(self.nodes):
            raise ValueError(f"the source gave {len(sample)} patches, "
                             f"the server has {len(self.nodes)}")
        return sample.reshape(len(self.nodes), 9, -1)

    def _take(self, resistance: np.ndarray) -> bool:
        """Codes, status and EMCY of every node, and their TPDOs packed (lock held); True
        when a node's mapping changed since the last sample."""
        self.samples += 1
        width = resistance.shape[2]
        new = codes.resistance_to_code(resistance, self._lsb)
        nodes = self.nodes
        measured = min(width, nodes[0].pillars)
        with locked(nodes):
            self._codes[:, :, :width] = new
            status = self._status_of(measured)
            plans = [answer_plan(node) for node in nodes]  # first: see pack_payloads
            payloads = pack_payloads(nodes, self._codes, status, plans)
        prepared = {}
        for node, plan, node_payloads in zip(nodes, plans, payloads, strict=True):
            messages: list[can.Message] = [TxMessage.frame(plan.cob_ids[p], node_payloads[p])
                                           for p in plan.order]
            prepared[node] = _Prepared(plan, node_payloads, messages)
        last, self._prepared = self._prepared, prepared
        return bool(last) and any(last[n].plan is not p.plan for n, p in prepared.items())

    def _status_of(self, measured: int) -> np.ndarray:
        """Every node's taxel status from the codes, EMCY where it changed. A sample with no
        reserved code (short, saturated, open) on a skin with no fault costs two reductions."""
        read = self._codes[:, :, :measured]
        if not self._faulty and read.min() > codes.SHORT and read.max() < codes.SATURATED:
            return self._no_fault
        status = codes.taxel_status(self._codes, measured)
        before = np.stack([node.faults.status for node in self.nodes])
        for i in np.flatnonzero((status != before).any(axis=1)).tolist():
            self.nodes[i].adopt(self._codes[i], status[i], True)  # EMCY
        self._faulty = bool(status.any())
        return status

    @staticmethod
    def _prepare(node: PatchNode) -> _Prepared:
        """One node's TPDOs packed from its current sample and mapping."""
        with locked([node]):
            plan = answer_plan(node)  # first: see pack_payloads
            payloads = pack_payloads([node], plans=[plan])[0]
        return _Prepared(plan, payloads,
                         [TxMessage.frame(plan.cob_ids[p], payloads[p]) for p in plan.order])

    # --- answers ----------------------------------------------------------------------

    def _answer(self, bus: ServerBus, sync_byte: int, received: float,
                cob_id: int = SYNC_COB_ID) -> None:
        bus.last_sync = time.monotonic()
        with self._lock:
            self.sync_count += 1
            bus.syncs += 1
            counter = bus.syncs
            reads = not self._sampler.running  # no sample clock: every SYNC reads a sample
            try:
                remapped = reads and self.failure is None and self._take(self._read())
            except Exception as err:
                failed: Exception | None = err
            else:
                failed = None
            prepared = self._prepared
        if failed is not None:
            self._fail(failed)
        if self.failure is not None:
            return
        if remapped:
            self._claim(bus)
        messages: list[can.Message] = []
        sync_of = bus.sync_of
        for node in bus.nodes:
            if sync_of.get(node) != cob_id:
                continue  # not configured, or consumes another SYNC
            node.answered = sync_byte
            if node.nmt.state != OPERATIONAL:
                continue
            ready = prepared.get(node)
            if ready is None or ready.plan.codec is not node.tpdo.codec:
                ready = self._prepare(node)  # remapped since the sample
            plan = ready.plan
            if plan.every_sync and not plan.layout.answered:
                messages += ready.messages
            else:
                payloads = _answered(ready, sync_byte)
                due = set(node.tpdo.due_on_sync(counter, payloads))
                messages += [TxMessage.frame(plan.cob_ids[p], payloads[p])
                             for p in plan.order if p in due]
        self._send(bus, messages)
        if messages and received > 0:
            took = time.time() - received
            bus.answer_s.append(took)
            if 0 < received - bus.last_received < took:
                bus.late += 1
        bus.last_received = received
        with self._quiet:
            bus.answered_at = time.monotonic()
            self._quiet.notify_all()

    def _send_events(self, now: float) -> None:
        """Event-driven TPDOs (types 254/255) due at ``now``, from the latest sample."""
        prepared = self._prepared
        for bus in self.buses:
            messages: list[can.Message] = []
            for node in bus.nodes:
                ready = prepared.get(node)
                if ready is None or not ready.plan.event or node.nmt.state != OPERATIONAL:
                    continue
                if ready.plan.codec is not node.tpdo.codec:
                    continue  # remapped since the sample: the next one has the new mapping
                payloads = _answered(ready, node.answered)
                due = set(node.tpdo.due_on_event(now, payloads))
                messages += [TxMessage.frame(ready.plan.cob_ids[p], payloads[p])
                             for p in ready.plan.order if p in due]
            if messages:
                self._send(bus, messages)

    def _send(self, bus: ServerBus, messages: list[can.Message]) -> None:
        network_bus = bus.network.bus
        assert network_bus is not None, "the network is not connected"
        send = network_bus.send
        sent, failed = 0, False
        with bus.send_lock:
            for msg in messages:
                try:
                    send(msg)
                except can.CanError as err:
                    logger.warning("TPDO 0x%03X not sent: %s", msg.arbitration_id, err)
                    failed = True
                else:
                    sent += 1
            bus.frames_sent += sent
        if failed:  # CiA 301 0x1029: the error behaviour of each node that could not send
            for node in bus.nodes:
                node.communication_error()

    # --- own frames -------------------------------------------------------------------

    def consumed_cob_ids(self, bus: int = 0) -> set[int]:
        """What the nodes of bus ``bus`` receive: NMT, SYNC, LSS and their SDO requests."""
        nodes = self.buses[bus].nodes
        return {0x000, SYNC_COB_ID, LSS_MASTER} | {node.sync_cob_id() for node in nodes} | \
            {int(node.store.sdo.rx_cobid) for node in nodes if node.configured}

    def _claim(self, bus: ServerBus) -> None:
        """Claim the COB-IDs the bus's nodes send, where the bus echoes them (and accept
        only what they consume, if asked)."""
        first = bus.own is None and self._accept_only_consumed  # later: claims only
        consumed = self.consumed_cob_ids(self.buses.index(bus)) if first else None
        claim_own_frames(bus, consumed)

    def _release(self, bus: ServerBus) -> None:
        release_own_frames(bus, accepted_only=self._accept_only_consumed)


def _answered(ready: _Prepared, sync_byte: int) -> list[bytes]:
    """The payloads with 0x2006 set to ``sync_byte`` wherever it is mapped."""
    answered = ready.plan.layout.answered
    if not answered:
        return ready.payloads
    payloads = list(ready.payloads)
    for p, at in answered:
        payload = bytearray(payloads[p])
        payload[at] = sync_byte
        payloads[p] = bytes(payload)
    return payloads
