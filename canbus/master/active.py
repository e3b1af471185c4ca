"""The active master: the host discovers, configures and starts its patches and watches them.

Start-up, per bus: boot-up and heartbeat consumers; canopen's SDO scan; every configured
patch that answers is identified (0x1018 product code 1), configured
(:mod:`canbus.master.patch_setup`; on a CAN FD bus its whole answer in one TPDO) and started
by NMT; a node at a force node's ID, or an unknown node whose predefined COB-IDs overlap
the force nodes', refuses the start; other unknown nodes are reported and left alone.
Then the force nodes boot and go OPERATIONAL (on a CAN FD bus with the whole sample in
one TPDO), and SYNC starts on every patch bus, unless the config says ``sync =
"external"``: then the host follows the SYNC another master produces. A configured patch
that is absent at start, or boots later, is configured when its boot-up (or first
heartbeat) arrives; one whose heartbeat stops is marked lost (:mod:`canbus.master.liveness`),
its channel goes offline and its force node publishes an all-invalid sample every
cycle until it is back, so no consumer keeps stale forces and every cycle counts.
"""

# canopen 2.4 ships py.typed but leaves SdoClient methods unannotated.
# mypy: disable-error-code="no-untyped-call"
from __future__ import annotations

import functools
import logging
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor, wait
from typing import TYPE_CHECKING

import can
from canopen.sdo.exceptions import SdoError

from canbus.master.buslink import BusLink
from canbus.master.cobids import force_cob_ids, node_cob_ids
from canbus.master.discovery import Identity, UnknownNode, read_identity, scan, sdo_client
from canbus.master.forcenode import ForceNode, map_fd
from canbus.master.patch_setup import (
    PatchSetup,
    configured_info,
    plan_setup,
    setup_patch,
    warn_if_unlike_config,
)
from canbus.master.records import PatchRecord
from canbus.pdo_codec import COB_ID_INVALID, TPDO_COMM
from skin.errors import BusError, SkinError

if TYPE_CHECKING:
    from canbus.master.host import HostManager

logger = logging.getLogger(__name__)

NMT_START, NMT_PRE_OPERATIONAL = 0x01, 0x80
SYNC_COB_ID, SDO_REQUEST = 0x080, 0x600
OPERATIONAL_STATE, STOPPED_STATE = 0x05, 0x04


class ActiveMaster:
    """The host runs its patches (module docstring)."""

    def __init__(self, host: HostManager) -> None:
        self.host = host
        self.scanning = False  # boot-ups and returns are left to the scan meanwhile

    def prepare(self) -> None:
        host = self.host
        host.executor = ThreadPoolExecutor(max_workers=min(8, len(host.patches)),
                                           thread_name_prefix="patch-setup")
        self.scanning = host.config.scan

    def planned(self, patch: PatchRecord) -> PatchSetup:
        """The set-up the host will make for a patch, before it answers."""
        return plan_setup(patch.node_id, patch.node.object_dictionary, patch.config.mode,
                          configured_info(patch.config), fd=patch.link.fd)

    def subscribe(self) -> None:
        for patch in self.host.patches.values():
            patch.link.network.add_node(patch.node)
            # Our heartbeat period holds once the set-up has written 0x1017.
            patch.link.monitor.watch(patch.node_id, judged=False)

    def start(self) -> None:
        host = self.host
        jobs = self._discover() if host.config.scan else []
        self._start_force_nodes()
        self._claim_own_frames()
        wait(jobs)
        for link in host.links.values():
            if link.dataplane is not None:
                link.dataplane.warm_up()
        if not host.config.sync_following:
            period_s = host.config.sync_period_ms / 1000.0
            for link in host.links.values():
                if link.dataplane is not None:
                    link.produce_sync(period_s, host.config.sync_counter).start()

    def stop(self) -> None:
        host = self.host
        if host.executor is not None:
            host.executor.shutdown(wait=True, cancel_futures=True)
        for link in host.links.values():
            link.release_own()
        for patch in host.patches.values():
            patch.force_node.on_cob_ids_changed = None
            patch.force_node.detach()
            network = patch.link.network
            if patch.node.id in network.nodes:
                del network[patch.node.id]

    # -- discovery and set-up ----------------------------------------------------------

    def _discover(self) -> list[Future[None]]:
        """Scan every bus, refuse collisions, set up the configured patches found, report
        the rest.

        Until the scan is over, boot-ups and heartbeats (queued before the start included)
        start no set-up or identification: the scan finds those nodes too (canopen's
        scanner also counts the nodes it hears), and an SDO transfer started meanwhile
        would take the scan's answers for its own."""
        host = self.host
        try:
            found = {name: scan(link.network, host.config.scan_ms / 1000.0)
                     for name, link in host.links.items()}
        finally:
            self.scanning = False
        jobs = []
        for name, nodes in found.items():
            link = host.links[name]
            for node_id in nodes:
                if node_id in host.force_ids:
                    raise BusError(f"node-ID {node_id} answers on {self._bus(link)} but is "
                                   f"the force node of patch {host.force_ids[node_id]}: "
                                   "change force_node")
            for node_id in nodes:
                patch = host.patches.get(node_id)
                if patch is not None and patch.link is link:
                    jobs.append(self.request_setup(patch, restart=False))
                elif patch is None and node_id not in host.config.other_nodes:
                    self._check_no_collision(link, node_id)
                    jobs.append(self._submit(functools.partial(self._identify, link),
                                             node_id))
        return [j for j in jobs if j is not None]

    def _check_no_collision(self, link: BusLink, node_id: int) -> None:
        ours: set[int] = set()
        for patch in self.host.patches.values():
            if patch.force_link is link:
                ours |= force_cob_ids(patch.config)
        clash = ours & set(node_cob_ids(node_id))
        if clash:
            listed = ", ".join(f"0x{c:03X}" for c in sorted(clash))
            raise BusError(f"node {node_id} on {self._bus(link)} may transmit on {listed}, "
                           "which the force nodes use: list it in host.other_nodes and change "
                           "the force COB-IDs")

    def _bus(self, link: BusLink) -> str:
        return "the bus" if len(self.host.links) == 1 else f"bus {link.name!r}"

    def _start_force_nodes(self) -> None:
        for patch in self.host.patches.values():
            force = patch.force_node
            force.attach(patch.force_link.network)
            if patch.force_link.fd:
                map_fd(force)
            if patch.config.force_cob_ids is not None:
                _set_tpdo_cob_ids(force, patch.config.force_cob_ids)
            force.on_tare = functools.partial(self.host.tare, patch.node_id)
            force.start()
            force.on_cob_ids_changed = self._claim_own_frames  # another master remapped it

    def _claim_own_frames(self) -> None:
        """What the host alone sends on each bus is claimed (:meth:`BusLink.claim_own`): the
        SYNC it produces, its force nodes' frames, its SDO requests to its patches."""
        host = self.host
        producing_sync = not host.config.sync_following
        for link in host.links.values():
            own: set[int] = set()
            if producing_sync and link.dataplane is not None:
                own.add(SYNC_COB_ID)
            for patch in host.patches.values():
                if patch.force_link is link:
                    own |= patch.force_node.cob_ids()
                if patch.link is link:
                    own.add(SDO_REQUEST + patch.node_id)
            link.claim_own(own)

    def _submit(self, job: Callable[[int], None], node_id: int) -> Future[None] | None:
        executor = self.host.executor
        if executor is None or not self.host.running:
            return None
        try:
            return executor.submit(job, node_id)
        except RuntimeError:  # shutting down
            return None

    def request_setup(self, patch: PatchRecord, *, restart: bool) -> Future[None] | None:
        """(Re)configure a patch; returns the set-up job that will do it. With ``restart``
        (a boot-up: the node was reset) a set-up in progress starts over; without, a patch
        being configured or operational is left as it is."""
        host = self.host
        with host._lock:
            if self.scanning:
                return None  # the scan finds it and configures it
            if not restart and patch.state in ("configuring", "operational"):
                return patch.job
            patch.generation += 1
            host.take_offline(patch, "configuring")
            if patch.queued:
                return patch.job
            patch.queued = True
            patch.job = self._submit(self._setup, patch.node_id)
            return patch.job

    def _setup(self, node_id: int) -> None:
        host = self.host
        patch = host.patches[node_id]
        with patch.sdo_lock:
            with host._lock:
                patch.queued = False
                generation = patch.generation
            try:
                identity = read_identity(patch.node.sdo)
                if identity.kind != "patch":
                    raise BusError(f"node {node_id} is not a patch: {_describe(identity)}")
                patch.node.nmt.send_command(NMT_PRE_OPERATIONAL)
                setup = setup_patch(patch.node, patch.config.mode,
                                    heartbeat_ms=host.config.heartbeat_ms, fd=patch.link.fd)
                warn_if_unlike_config(patch.config, setup.info)
                host.decoders.get(patch.config, setup)  # built and warmed here, not in a cycle
            except (SdoError, can.CanError, SkinError) as err:
                with host._lock:
                    if generation == patch.generation and host.running:
                        host.set_state(patch, "failed", f"set-up failed: {err}")
                        logger.error("patch %d: set-up failed: %s", node_id, err)
                return
            with host._lock:
                if generation != patch.generation or not host.running:
                    return  # a newer request (e.g. a boot-up) is queued and starts over
                host.go_online(patch, setup)
                patch.node.nmt.send_command(NMT_START)
        logger.info("patch %d operational on bus %r (%s%s, %s)", node_id, patch.link.name,
                    setup.mode, ", CAN FD" if patch.link.fd else "", patch.config.decoder)

    def _identify(self, link: BusLink, node_id: int) -> None:
        host = self.host
        identity: Identity | None
        try:
            with sdo_client(link.network, node_id,
                            timeout_s=host.config.sdo_timeout_ms / 1000.0) as client:
                identity = read_identity(client)
        except (SdoError, can.CanError):
            identity = None
        if identity is None:
            reason = "did not answer SDO 0x1018"
        elif identity.kind == "patch":
            reason = "a patch that is not in the config"
        else:
            reason = f"not managed ({_describe(identity)})"
        host.report_unknown(UnknownNode(node_id, identity, reason))

    # -- bus events (notifier and monitor threads: record and hand on) ----------------

    def on_unknown_boot(self, link: BusLink, node_id: int) -> None:
        if not self.scanning:  # else the scan identifies it
            self._submit(functools.partial(self._identify, link), node_id)

    def on_patch_boot(self, patch: PatchRecord) -> None:
        logger.info("patch %d booted: configuring it", patch.node_id)
        patch.link.monitor.judge(patch.node_id, False)  # a boot resets 0x1017 to its default
        self.request_setup(patch, restart=True)

    def on_return(self, patch: PatchRecord, state: int) -> None:
        host = self.host
        with host._lock:
            resume = (patch.state == "lost" and state == OPERATIONAL_STATE
                      and patch.setup is not None and patch.channel is None)
            if resume:
                assert patch.setup is not None
                host.go_online(patch, patch.setup)
                logger.info("patch %d is back", patch.node_id)
                return
        self.request_setup(patch, restart=False)  # heard without a boot-up: configure it

    def on_change(self, patch: PatchRecord, state: int) -> None:
        del patch, state  # an active master's patches change state by its own commands

    def on_lost(self, patch: PatchRecord) -> None:
        host = self.host
        with host._lock:
            if patch.state not in ("operational", "configuring", "stopped"):
                return
            patch.generation += 1  # a set-up in progress is void
            host.take_offline(patch, "lost")
        logger.warning("patch %d lost (no heartbeat for %.0f ms)", patch.node_id,
                       patch.link.monitor.lost_after_s * 1000)


def _describe(identity: Identity) -> str:
    return (f"vendor 0x{identity.vendor:08X}, product {identity.product}, "
            f"revision 0x{identity.revision:08X}, serial {identity.serial}")


def _set_tpdo_cob_ids(force: ForceNode, cob_ids: tuple[int, ...]) -> None:
    """Move the force node's TPDOs to the configured COB-IDs (CiA 301: invalidate first);
    a TPDO that is invalid (the CAN FD mapping uses TPDO 1 alone) stays invalid."""
    for n, cob_id in enumerate(cob_ids):
        index = TPDO_COMM + n
        old = int(force.store.value(index, 1))
        force.store.set_data(index, 1, (old | COB_ID_INVALID).to_bytes(4, "little"))
        keep_invalid = old & COB_ID_INVALID
        force.store.set_data(index, 1, (cob_id | keep_invalid).to_bytes(4, "little"))
