"""The active master: the host discovers, configures and starts its patches and watches them.

Start-up, per bus: boot-up and heartbeat consumers; canopen's SDO scan; every configured
patch that answers is set up (:mod:`canbus.master.setup_jobs`: identified by 0x1018,
configured by :mod:`canbus.master.patch_setup`, on a CAN FD bus its whole answer in one
TPDO, started by NMT); a node at a force node's ID, or an unknown node whose predefined
COB-IDs overlap the force nodes', refuses the start; other unknown nodes are reported and
left alone. Then the force nodes boot and go OPERATIONAL (on a CAN FD bus with the whole
sample in one TPDO), and SYNC starts on every patch bus, unless the config says ``sync =
"external"``: then the host follows the SYNC another master produces.

Afterwards the bus drives it. What it sees is recorded in the patch states
(:mod:`canbus.master.patchstate`), which derive each patch's state: a boot-up begins a
new incarnation (set up again), a heartbeat after silence resumes an OPERATIONAL patch as
it was and has any other configured again, a lost one (:mod:`canbus.master.liveness`)
goes offline: its force node publishes an all-invalid sample every cycle until it is
back, so no consumer keeps stale forces and every cycle counts. A foreign node heard at
a force node's ID mid-run (its boot-up, heartbeat or EMCY) is reported; the force node
keeps publishing.
"""

# canopen 2.4 ships py.typed but leaves SdoClient methods unannotated.
# mypy: disable-error-code="no-untyped-call"
from __future__ import annotations

import functools
import logging
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, wait

import can
from canopen.sdo.exceptions import SdoError

from canbus.echoes import echo_ledger
from canbus.identity import Identity
from canbus.master.buslink import BusLink
from canbus.master.cobids import force_cob_ids, node_cob_ids
from canbus.master.discovery import (
    HaltableSdoClient,
    UnknownNode,
    read_identity,
    scan,
    sdo_client,
)
from canbus.master.forcenode import ForceNode, map_fd
from canbus.master.patch_setup import PatchSetup, configured_info, plan_setup
from canbus.master.policy import HostParts
from canbus.master.records import PatchRecord
from canbus.master.setup_jobs import SetupJobs, describe_identity
from canbus.pdo_codec import COB_ID_INVALID, TPDO_COMM
from canbus.ratelog import RateLimitedLog
from skin.errors import BusError

logger = logging.getLogger(__name__)

SYNC_COB_ID, SDO_REQUEST, EMCY, HEARTBEAT = 0x080, 0x600, 0x080, 0x700
WAIT_SLICE_S = 0.05  # how often start-up waits look at the stop event
CONFLICT_LOG_S = 60.0  # a foreign node at a force node's ID: one line a minute at most


class ActiveMaster:
    """The host runs its patches (module docstring)."""

    def __init__(self, parts: HostParts) -> None:
        self.parts = parts
        self.scanning = False  # boot-ups and returns are left to the scan meanwhile
        self.jobs: SetupJobs | None = None
        self._clients: list[HaltableSdoClient] = []  # identifying unknown nodes
        self._clients_lock = threading.Lock()
        self._foreign: dict[int, tuple[str, int]] = {}  # force node-ID -> first seen, frames
        self._foreign_log = RateLimitedLog(logger, interval_s=CONFLICT_LOG_S, burst=1)
        self._watched: list[tuple[BusLink, int, Callable[[int, bytearray, float], None]]] = []

    def prepare(self) -> None:
        self.scanning = self.parts.config.scan
        self.jobs = SetupJobs(self.parts)
        self.jobs.paused = self.scanning
        for patch in self.parts.patches.values():  # halted by an earlier stop
            if isinstance(patch.node.sdo, HaltableSdoClient):
                patch.node.sdo.resume()

    def planned(self, patch: PatchRecord) -> PatchSetup:
        """The set-up the host will make for a patch, before it answers."""
        return plan_setup(patch.node_id, patch.node.object_dictionary, patch.config.mode,
                          configured_info(patch.config), fd=patch.link.fd)

    def subscribe(self) -> None:
        for patch in self.parts.patches.values():
            patch.link.network.add_node(patch.node)
            # Our heartbeat period holds once the set-up has written 0x1017.
            patch.link.monitor.watch(patch.node_id, judged=False)
            self._watch_force_id(patch)

    def start(self) -> None:
        parts = self.parts
        jobs = self._discover() if parts.config.scan else []
        if parts.stopping.is_set():
            return
        self._start_force_nodes()
        self._claim_own_frames()
        pending = set(jobs)
        while pending and not parts.stopping.is_set():
            _, pending = wait(pending, timeout=WAIT_SLICE_S)
        if parts.stopping.is_set():
            return
        for link in parts.links.values():
            if link.dataplane is not None:
                link.dataplane.warm_up()
        if not parts.config.sync_following:
            period_s = parts.config.sync_period_ms / 1000.0
            for link in parts.links.values():
                if link.dataplane is not None:
                    link.produce_sync(period_s, parts.config.sync_counter).start()

    def stop(self) -> None:
        parts = self.parts
        with self._clients_lock:
            clients = list(self._clients)
        for client in clients:
            client.halt()
        if self.jobs is not None:
            self.jobs.stop()
        for link, cob_id, handler in self._watched:
            if handler in link.network.subscribers.get(cob_id, []):
                link.network.unsubscribe(cob_id, handler)
            echo_ledger(link.bus).forget([cob_id])
        self._watched.clear()
        for link in parts.links.values():
            link.release_own()
        for patch in parts.patches.values():
            patch.force_node.on_cob_ids_changed = None
            patch.force_node.detach()
            _remove_node(patch)
        self._foreign_log.flush()

    # -- discovery ---------------------------------------------------------------------

    def _discover(self) -> list[Future[None]]:
        """Scan every bus, refuse collisions, set up the configured patches found, report
        the rest.

        Until the scan is over, boot-ups and heartbeats (queued before the start included)
        start no set-up or identification: the scan finds those nodes too (canopen's
        scanner also counts the nodes it hears), and an SDO transfer started meanwhile
        would take the scan's answers for its own."""
        parts = self.parts
        assert self.jobs is not None, "prepare() first"
        try:
            found = {name: scan(link.network, parts.config.scan_ms / 1000.0,
                                halt=parts.stopping)
                     for name, link in parts.links.items()}
        finally:
            self.scanning = False
            self.jobs.paused = False
        jobs: list[Future[None] | None] = []
        for name, nodes in found.items():
            link = parts.links[name]
            for node_id in nodes:
                if node_id in parts.force_ids:
                    raise BusError(f"node-ID {node_id} answers on {parts.bus_name(link)} but "
                                   f"is the force node of patch {parts.force_ids[node_id]}: "
                                   "change force_node")
            for node_id in nodes:
                patch = parts.patches.get(node_id)
                if patch is not None and patch.link is link:
                    parts.states.heard(node_id)
                elif patch is None and node_id not in parts.config.other_nodes:
                    self._check_no_collision(link, node_id)
                    jobs.append(self.jobs.submit(functools.partial(self._identify, link),
                                                 node_id))
        # The patches found, and those heard meanwhile (a boot-up during the scan).
        jobs.extend(self.jobs.ensure(patch) for patch in parts.patches.values())
        return [j for j in jobs if j is not None]

    def _check_no_collision(self, link: BusLink, node_id: int) -> None:
        ours: set[int] = set()
        for patch in self.parts.patches.values():
            if patch.force_link is link:
                ours |= force_cob_ids(patch.config)
        clash = ours & set(node_cob_ids(node_id))
        if clash:
            listed = ", ".join(f"0x{c:03X}" for c in sorted(clash))
            raise BusError(f"node {node_id} on {self.parts.bus_name(link)} may transmit on "
                           f"{listed}, which the force nodes use: list it in "
                           "host.other_nodes and change the force COB-IDs")

    def _identify(self, link: BusLink, node_id: int) -> None:
        parts = self.parts
        identity: Identity | None
        try:
            with sdo_client(link.network, node_id,
                            timeout_s=parts.config.sdo_timeout_ms / 1000.0) as client:
                with self._clients_lock:
                    self._clients.append(client)
                try:
                    identity = read_identity(client)
                finally:
                    with self._clients_lock:
                        self._clients.remove(client)
        except (SdoError, can.CanError):
            identity = None
        except Exception as err:  # a garbled answer: not identified, and said so
            logger.warning("node %d: identifying it failed: %s", node_id, err)
            identity = None
        if parts.stopping.is_set():
            return
        if identity is None:
            reason = "did not answer SDO 0x1018"
        elif identity.kind == "patch":
            reason = "a patch that is not in the config"
        else:
            reason = f"not managed ({describe_identity(identity)})"
        parts.report_unknown(UnknownNode(node_id, identity, reason))

    # -- force nodes -------------------------------------------------------------------

    def _start_force_nodes(self) -> None:
        for patch in self.parts.patches.values():
            force = patch.force_node
            force.attach(patch.force_link.network)
            if patch.force_link.fd:
                map_fd(force)
            if patch.config.force_cob_ids is not None:
                _set_tpdo_cob_ids(force, patch.config.force_cob_ids)
            force.on_tare = functools.partial(self.parts.tare, patch.node_id)
            force.start()
            force.on_cob_ids_changed = self._claim_own_frames  # another master remapped it

    def _claim_own_frames(self) -> None:
        """What the host alone sends on each bus is claimed (:meth:`BusLink.claim_own`): the
        SYNC it produces, its force nodes' frames, its SDO requests to its patches; not
        what :meth:`_watch_force_id` audits, where another node must be heard."""
        parts = self.parts
        producing_sync = not parts.config.sync_following
        for link in parts.links.values():
            own: set[int] = set()
            if producing_sync and link.dataplane is not None:
                own.add(SYNC_COB_ID)
            for patch in parts.patches.values():
                if patch.force_link is link:
                    own |= patch.force_node.cob_ids() - _audited(patch.force_id)
                if patch.link is link:
                    own.add(SDO_REQUEST + patch.node_id)
            link.claim_own(own)

    def _watch_force_id(self, patch: PatchRecord) -> None:
        """Hear a foreign node at the force node's ID: its boot-up or heartbeat, its EMCY
        (a force node sends none). Audited before the force node boots, so each of its
        own frames there is noted before it is sent (:mod:`canbus.echoes`)."""
        link, force_id = patch.force_link, patch.force_id
        echo_ledger(link.bus).audit(_audited(force_id))
        for cob_id, what in ((HEARTBEAT + force_id, "a boot-up or heartbeat"),
                             (EMCY + force_id, "an EMCY")):
            handler = functools.partial(self._foreign_frame, patch, what)
            link.network.subscribe(cob_id, handler)
            self._watched.append((link, cob_id, handler))

    def _foreign_frame(self, patch: PatchRecord, what: str, can_id: int, data: bytearray,
                       timestamp: float) -> None:
        if echo_ledger(patch.force_link.bus).is_echo(can_id, data):
            return
        force_id = patch.force_id
        first, frames = self._foreign.get(force_id, (time.strftime("%H:%M:%S"), 0))
        self._foreign[force_id] = (first, frames + 1)
        patch.force_conflict = (f"another node transmits at force node {force_id}'s ID "
                                f"({what} on 0x{can_id:03X}; {frames + 1} frame(s) since "
                                f"{first})")
        self._foreign_log.log(
            logging.WARNING, force_id, "node %d: another node transmits at the ID of patch "
            "%d's force node on %s (%s on 0x%03X): the force node keeps publishing, but a "
            "master may read the other's frames; give that node another ID or change "
            "force_node", force_id, patch.node_id, self.parts.bus_name(patch.force_link),
            what, can_id)

    # -- bus events (notifier and monitor threads: record and hand on) ----------------

    def on_unknown_boot(self, link: BusLink, node_id: int) -> None:
        if not self.scanning and self.jobs is not None:  # else the scan identifies it
            self.jobs.submit(functools.partial(self._identify, link), node_id)

    def on_patch_boot(self, patch: PatchRecord) -> None:
        logger.debug("patch %d booted", patch.node_id)  # its state line follows
        patch.link.monitor.judge(patch.node_id, False)  # a boot resets 0x1017 to its default
        self.parts.states.booted(patch.node_id)
        self._ensure(patch)

    def on_return(self, patch: PatchRecord, state: int) -> None:
        self.parts.states.returned(patch.node_id, state)
        self._ensure(patch)

    def on_change(self, patch: PatchRecord, state: int) -> None:
        del patch, state  # an active master's patches change state by its own commands

    def on_lost(self, patch: PatchRecord) -> None:
        self.parts.states.recheck(patch.node_id)

    def _ensure(self, patch: PatchRecord) -> None:
        if self.jobs is not None and not self.scanning:
            self.jobs.ensure(patch)


def _audited(force_id: int) -> frozenset[int]:
    """The force node's COB-IDs where the host listens for another node at its ID."""
    return frozenset((HEARTBEAT + force_id, EMCY + force_id))


def _remove_node(patch: PatchRecord) -> None:
    """Take the patch's node off its network, however far adding it got (a stop may come
    in the middle of canopen's ``add_node``)."""
    network, node = patch.link.network, patch.node
    node_id = int(node.id or 0)
    subscriptions = [(0x700 + node_id, node.nmt.on_heartbeat),
                     (0x80 + node_id, node.emcy.on_emcy), (0, node.nmt.on_command),
                     *((sdo.tx_cobid, sdo.on_response) for sdo in node.sdo_channels)]
    if network.nodes.get(node_id) is node:
        if node.has_network():
            for cob_id, callback in subscriptions:  # complete a half-done add_node: the
                network.subscribe(cob_id, callback)  # removal unsubscribes every one
        del network[node_id]
    for cob_id, callback in subscriptions:  # whatever is left of it
        if callback in network.subscribers.get(cob_id, []):
            network.unsubscribe(cob_id, callback)


def _set_tpdo_cob_ids(force: ForceNode, cob_ids: tuple[int, ...]) -> None:
    """Move the force node's TPDOs to the configured COB-IDs (CiA 301: invalidate first);
    a TPDO that is invalid (the CAN FD mapping uses TPDO 1 alone) stays invalid."""
    for n, cob_id in enumerate(cob_ids):
        index = TPDO_COMM + n
        old = int(force.store.value(index, 1))
        force.store.set_data(index, 1, (old | COB_ID_INVALID).to_bytes(4, "little"))
        keep_invalid = old & COB_ID_INVALID
        force.store.set_data(index, 1, (cob_id | keep_invalid).to_bytes(4, "little"))
