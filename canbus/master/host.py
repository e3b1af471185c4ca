"""The host manager: the CANopen master of the skin's patches and the publisher of their forces.

::

    with HostManager(bus, load_host_config("host.toml")) as host:
        host.on_forces(print)                      # callback(frame: ForceFrame)
        for frame in host.frames(timeout=1.0):     # or iterate
            ...
        host.health()                              # {node_id: PatchHealth}
        host.tare(1)                               # re-zero patch 1 (refused while loaded)

Two planes on one bus and one notifier thread. The management plane is canopen: a
``Network`` on the caller's bus, one ``RemoteNode`` per configured patch (SDO, NMT,
EMCY), boot-up and heartbeat consumers, a worker pool that configures patches (SDO
waits for responses that arrive on the notifier thread, so it never runs there). The
data plane is :class:`~canbus.master.dataplane.DataPlane`, a second listener on canopen's
notifier: it assembles each patch's PDOs per SYNC cycle, decodes and publishes them
through the patch's :class:`~canbus.master.forcenode.ForceNode`, and hands the frames here.

Start-up: heartbeat and boot-up consumers; canopen's SDO scan (``host.scan``); every
configured patch that answers is identified (0x1018 product code 1), configured
(:mod:`canbus.master.patch_setup`) and started by NMT; a node at a force node's ID, or an
unknown node whose predefined COB-IDs overlap the force nodes', refuses the start;
other unknown nodes are reported and left alone. Then the force nodes boot and go
OPERATIONAL, and SYNC starts. A configured patch that is absent at start, or boots
later, is configured when its boot-up (or first heartbeat) arrives; one whose heartbeat
stops is marked lost (:mod:`canbus.master.liveness`), its channel leaves the data plane and
its force node publishes one all-invalid sample, so no consumer keeps stale forces.

Listen-only (``listen_only=True`` or ``host.listen_only``): another master runs the
patches, or a recording is replayed onto the bus, and the host only decodes. It
transmits nothing (no scan, SDO, NMT, SYNC, force node or force PDO). Each patch's
channel is built from the config (:func:`~canbus.master.patch_setup.plan_setup`: the mapping
the host would write for its mode; constants and R0 as a patch holding the configured
ones reports them); every SYNC received opens a cycle (:class:`~canbus.master.sync_producer.
SyncFollower`). A patch is decoded while it is OPERATIONAL as the bus shows it: the NMT
commands any master sends it, its boot-up, its heartbeats (lost and back as above).
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field, replace
from typing import Any, Self

import can
import canopen
import numpy as np
from canopen.emcy import EmcyError
from canopen.sdo.exceptions import SdoError
from numpy.typing import NDArray

from canbus.master.baseline import Baseline, PatchLoadedError
from canbus.master.dataplane import DataPlane, ForceFrame, PatchChannel, PdoRouter
from canbus.master.discovery import (
    BootListener,
    Identity,
    UnknownNode,
    read_identity,
    scan,
    sdo_client,
)
from canbus.master.fanout import FrameCallback, FrameFanout
from canbus.master.forcenode import ForceNode
from canbus.master.hostconfig import (
    HostConfig,
    PatchConfig,
    force_cob_ids,
    load_host_config,
    node_cob_ids,
)
from canbus.master.liveness import HeartbeatMonitor
from canbus.master.patch_setup import PatchInfo, PatchSetup, patch_info, plan_setup, setup_patch
from canbus.master.sync_producer import SyncFollower, SyncProducer
from canbus.od import load_od
from canbus.txmessage import TxMessage
from decoder.protocol import BaseDecoder, Decoder
from decoder.reasons import Reason
from decoder.registry import create_decoder, load_decoder
from skin.constants import DEFAULT_CONSTANTS, TAXELS_PER_PATCH
from skin.errors import BusError, SkinError

__all__ = ["ForceFrame", "HostManager", "PatchHealth", "PatchLoadedError"]

logger = logging.getLogger(__name__)

NOTIFIER_CYCLE_S = 0.05  # canopen's notifier recv() timeout: stop() joins within one cycle
NMT_COB_ID = 0x000
EMCY_LOG_KEPT = 256
"""EMCYs of a patch kept in canopen's ``EmcyConsumer.log`` (trimmed to this many once it
holds twice as many): a long-running host with a flapping taxel must not grow without
bound. ``emcy.active`` is canopen's own, cleared by each error reset."""
NMT_START, NMT_PRE_OPERATIONAL = 0x01, 0x80
OPERATIONAL_STATE, STOPPED_STATE = 0x05, 0x04
DEVICE_HARDWARE, ERROR_RESET = 0x5000, 0x0000
STATES = ("absent", "configuring", "operational", "stopped", "lost", "failed")
# Listen-only: the state an NMT command (from any master) puts a patch in.
_NMT_COMMANDS = {NMT_START: "operational", 0x02: "stopped", NMT_PRE_OPERATIONAL: "configuring",
                 0x81: "configuring", 0x82: "configuring"}  # resets: a boot-up follows



@dataclass(frozen=True)
class PatchHealth:
    """One patch as the host sees it.

    ``state``: ``absent`` (never heard), ``configuring``, ``operational``, ``lost``
    (heartbeat overdue) or ``failed`` (set-up refused or timed out; ``error`` says why).
    Listen-only: ``configuring`` is pre-operational (booted, not started by its master),
    ``stopped`` is stopped by an NMT command; ``failed`` does not occur.
    """

    state: str
    lost: bool
    faulty_taxels: tuple[int, ...]  # reported by EMCY, masked in the output
    last_heartbeat: float | None  # time.time() of the last heartbeat
    samples: int  # force frames published for the patch
    incomplete: int  # of which incomplete
    error: str | None = None


@dataclass
class _Patch:
    config: PatchConfig
    node: canopen.RemoteNode
    force_node: ForceNode
    masked: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(TAXELS_PER_PATCH, bool))
    state: str = "absent"
    error: str | None = None
    setup: PatchSetup | None = None
    channel: PatchChannel | None = None
    baseline: Baseline | None = None
    generation: int = 0
    queued: bool = False  # a set-up job is queued and has not started
    job: Future[None] | None = None  # the latest set-up job
    samples: int = 0
    incomplete: int = 0
    last: ForceFrame | None = None
    sdo_lock: threading.Lock = field(default_factory=threading.Lock)


class HostManager:
    """Discovers, configures, starts and watches the patches of ``config`` on ``bus``.

    The caller owns ``bus`` (it is not shut down on stop). ``on_unknown`` is called
    with an :class:`~canbus.master.discovery.UnknownNode` for every node the host does not
    manage (found by the scan or by its boot-up); the host never writes to such a node.
    ``listen_only`` (default: ``config.listen_only``): decode what another master runs
    and send nothing (module docstring).
    """

    def __init__(self, bus: can.BusABC, config: HostConfig, *,
                 on_unknown: Callable[[UnknownNode], None] | None = None,
                 listen_only: bool | None = None) -> None:
        self.bus = bus
        config = config.check()
        if listen_only is not None:
            config = replace(config, listen_only=listen_only)
        self.config = config
        self.listen_only = config.listen_only
        self.on_unknown = on_unknown
        self.network = canopen.Network(bus)
        self.network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
        self._dataplane: DataPlane | None = None  # built by start(): it owns a thread
        self._sync: SyncProducer | SyncFollower | None = None
        self.monitor = HeartbeatMonitor(
            self.network, self.config.heartbeat_ms, on_boot=self._on_patch_boot,
            on_lost=self._on_lost, on_return=self._on_return,
            on_change=self._on_change if self.listen_only else None)
        self.boots = BootListener(self.network, self._on_any_boot)
        self.unknown_nodes: dict[int, UnknownNode] = {}
        self._patches: dict[int, _Patch] = {}
        for patch in self.config.patches:
            node = canopen.RemoteNode(patch.node_id, load_od("skin-patch", patch.node_id))
            node.sdo.RESPONSE_TIMEOUT = self.config.sdo_timeout_ms / 1000.0
            force = ForceNode(patch.force_node, patch.node_id,
                              heartbeat_ms=self.config.force_heartbeat_ms)
            self._patches[patch.node_id] = _Patch(patch, node, force)
            node.emcy.add_callback(self._emcy_handler(self._patches[patch.node_id]))
            if self.listen_only:  # the channel is known from the config: no set-up job
                self._patches[patch.node_id].setup = plan_setup(
                    patch.node_id, node.object_dictionary, patch.mode, configured_info(patch))
        self._force_ids = {p.force_node: p.node_id for p in self.config.patches}
        self._decoders: dict[tuple[str, str, object], Decoder] = {}
        self._warm: set[tuple[str, str, object, int]] = set()
        self.fanout = FrameFanout()
        self._lock = threading.RLock()
        self._changed = threading.Condition(self._lock)  # notified on every state change
        self._executor: ThreadPoolExecutor | None = None
        self._running = False
        self._scanning = False  # boot-ups and returns are left to the scan meanwhile

    @classmethod
    def from_config(cls, path: str | os.PathLike[str], bus: can.BusABC, **kwargs: Any) -> Self:
        """A host for the config file at ``path`` (see ``examples/host.toml``)."""
        return cls(bus, load_host_config(path), **kwargs)

    # -- lifecycle ---------------------------------------------------------------------

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> None:
        """Discover and configure the patches present, boot the force nodes, start SYNC.

        Returns when the patches that answered the scan are configured (or failed).
        Raises :class:`~skin.errors.BusError` if a node on the bus would collide with a
        force node; the host is then stopped again. Listen-only: builds the decoders and
        starts listening; nothing is sent.
        """
        if self._running:
            raise BusError("the host is already running")
        self._running = True
        try:
            if self.listen_only:  # decoders built (and tables warmed) before any frame
                for patch in self._patches.values():
                    assert patch.setup is not None
                    self._decoder(patch.config, patch.setup)
        except BaseException:
            self._running = False
            raise
        dataplane = DataPlane(self.bus, sync_window_s=self.config.sync_window_ms / 1000.0)
        self._dataplane = dataplane
        dataplane.subscribe(self._on_frames)
        sync: SyncProducer | SyncFollower
        if self.listen_only:
            sync = SyncFollower(dataplane.on_sync)
        else:
            self._executor = ThreadPoolExecutor(max_workers=min(8, len(self._patches)),
                                                thread_name_prefix="patch-setup")
            sync = SyncProducer(self.bus, self.config.sync_period_ms / 1000.0,
                                on_sync=dataplane.on_sync, counter=self.config.sync_counter)
        self._sync = sync
        # canopen's notifier, built here rather than by Network.connect() (which, on a bus
        # it is given, builds just this) so that it starts with every listener: the data
        # plane takes its patches' PDOs, canopen's listener and the SYNC follower get
        # every other frame, from the first.
        others: list[can.Listener] = [*self.network.listeners]
        if isinstance(sync, SyncFollower):
            others.append(sync)
        listeners: list[can.Listener] = [PdoRouter(dataplane, others)]
        self._scanning = isinstance(sync, SyncProducer) and self.config.scan
        try:
            self.boots.start()
            for patch in self._patches.values():
                if self.listen_only:  # EMCY only: no SDO client taking the bus's responses
                    self.network.subscribe(0x80 + patch.config.node_id, patch.node.emcy.on_emcy)
                else:
                    self.network.add_node(patch.node)
                # Our heartbeat period holds once the set-up has written 0x1017.
                self.monitor.watch(patch.config.node_id, judged=self.listen_only)
            if self.listen_only:
                self.network.subscribe(NMT_COB_ID, self._on_nmt)
            self.network.notifier = can.Notifier(self.bus, listeners,
                                                 timeout=self.network.NOTIFIER_CYCLE)
            self.monitor.start()
            if isinstance(sync, SyncProducer):
                jobs = self._discover() if self.config.scan else []
                self._start_force_nodes()
                wait(jobs)
                sync.start()
        except BaseException:
            self.stop()
            raise

    def stop(self) -> None:
        """Stop SYNC, publish what is pending, stop consumers and force nodes, end iterators."""
        if not self._running:
            return
        self._running = False
        if self._sync is not None:
            self._sync.stop()
            if self._sync.cycle:  # the last cycle's PDOs arrive within its window: wait
                threading.Event().wait(self.config.sync_window_ms / 1000.0)
        if self._dataplane is not None:
            self._dataplane.flush()
        self.monitor.stop()
        self.boots.stop()
        if self._executor is not None:
            self._executor.shutdown(wait=True, cancel_futures=True)
        for patch in self._patches.values():
            patch.force_node.detach()
            if patch.node.id in self.network.nodes:
                del self.network[patch.node.id]
            _unsubscribe(self.network, 0x80 + patch.config.node_id, patch.node.emcy.on_emcy)
        _unsubscribe(self.network, NMT_COB_ID, self._on_nmt)
        if self.network.notifier is not None:  # also stops the data plane (a listener)
            self.network.notifier.stop(self.network.NOTIFIER_SHUTDOWN_TIMEOUT)
            self.network.notifier = None
        elif self._dataplane is not None:
            self._dataplane.stop()
        self.fanout.close()

    def _discover(self) -> list[Future[None]]:
        """Scan, refuse collisions, set up the configured patches found, report the rest.

        Until the scan is over, boot-ups and heartbeats (queued before the start included)
        start no set-up or identification: the scan finds those nodes too (canopen's
        scanner also counts the nodes it hears), and an SDO transfer started meanwhile
        would take the scan's answers for its own."""
        try:
            found = scan(self.network, self.config.scan_ms / 1000.0)
        finally:
            self._scanning = False
        for node_id in found:
            if node_id in self._force_ids:
                raise BusError(f"node-ID {node_id} answers on the bus but is the force node "
                               f"of patch {self._force_ids[node_id]}: change force_node")
        jobs = []
        for node_id in found:
            if node_id in self._patches:
                jobs.append(self._request_setup(node_id, restart=False))
            elif node_id not in self.config.other_nodes:
                self._check_no_collision(node_id)
                jobs.append(self._submit(self._identify, node_id))
        return [j for j in jobs if j is not None]

    def _check_no_collision(self, node_id: int) -> None:
        ours: set[int] = set()
        for patch in self._patches.values():
            ours |= force_cob_ids(patch.config)
        clash = ours & set(node_cob_ids(node_id))
        if clash:
            listed = ", ".join(f"0x{c:03X}" for c in sorted(clash))
            raise BusError(f"node {node_id} on the bus may transmit on {listed}, which the "
                           "force nodes use: list it in host.other_nodes and change the "
                           "force COB-IDs")

    def _start_force_nodes(self) -> None:
        for patch in self._patches.values():
            force = patch.force_node
            force.attach(self.network)
            if patch.config.force_cob_ids is not None:
                _set_tpdo_cob_ids(force, patch.config.force_cob_ids)
            force.start()

    # -- the public API ----------------------------------------------------------------

    @property
    def dataplane(self) -> DataPlane:
        """The data plane of the current (or last) run."""
        if self._dataplane is None:
            raise BusError("the host has not been started")
        return self._dataplane

    @property
    def sync(self) -> SyncProducer | SyncFollower:
        """The SYNC producer (listen-only: follower) of the current (or last) run."""
        if self._sync is None:
            raise BusError("the host has not been started")
        return self._sync

    def on_forces(self, callback: FrameCallback) -> None:
        """Call ``callback(frame)`` for every force frame, on the data plane's thread.

        Keep it short: the next patch's frames wait for it. An exception is logged with
        its traceback and counted in :attr:`callback_errors`; the other callbacks run.
        """
        self.fanout.add_callback(callback)

    def remove_callback(self, callback: FrameCallback) -> None:
        self.fanout.remove_callback(callback)

    @property
    def callback_errors(self) -> int:
        """Exceptions raised by force and ``on_unknown`` callbacks (logged)."""
        return self.fanout.callback_errors

    @property
    def api_dropped(self) -> int:
        """Frames the ``frames()`` iterators had no room for (oldest dropped)."""
        return self.fanout.dropped

    def frames(self, timeout: float | None = 1.0, *,
               maxsize: int | None = None) -> Iterator[ForceFrame]:
        """An iterator of force frames from now on, in the order they were published.

        It ends when no frame arrives for ``timeout`` seconds (``None``: wait for ever)
        or when the host stops. Its queue holds ``maxsize`` frames (default
        ``host.queue_size``); when the consumer falls behind, the oldest are dropped
        and counted in :attr:`api_dropped`, never blocking the data plane.
        """
        return self.fanout.iterate(maxsize or self.config.queue_size, timeout,
                                   lambda: self._running)

    def health(self) -> dict[int, PatchHealth]:
        """Every configured patch's state, by node-ID."""
        out = {}
        with self._lock:
            for node_id, p in self._patches.items():
                lost = p.state == "lost"
                out[node_id] = PatchHealth(
                    state=p.state, lost=lost,
                    faulty_taxels=tuple(int(k) for k in np.flatnonzero(p.masked)),
                    last_heartbeat=self.monitor.last_heartbeat(node_id),
                    samples=p.samples, incomplete=p.incomplete, error=p.error)
        return out

    def tare(self, node_id: int) -> None:
        """Re-zero patch ``node_id`` at its last complete sample.

        Raises :class:`~canbus.master.baseline.PatchLoadedError` while any taxel of the patch
        reads more than ``host.tare_threshold_N`` (or before its first sample), and
        :class:`~skin.errors.BusError` if the patch is not operational.
        """
        with self._lock:
            patch = self._patch(node_id)
            if patch.state != "operational" or patch.baseline is None or patch.channel is None:
                raise BusError(f"patch {node_id} is {patch.state}: nothing to tare")
            last = patch.last
            raw = self.dataplane.raw_sample(node_id)
            patch.baseline.tare(raw, None if last is None else last.force_N,
                                None if last is None else last.valid, node_id=node_id)

    def wait_operational(self, node_ids: list[int] | None = None, timeout: float = 10.0) -> bool:
        """Wait until the patches (default: all configured) are operational; False on
        time-out."""
        wanted = list(self._patches) if node_ids is None else node_ids
        with self._changed:
            return self._changed.wait_for(
                lambda: all(self._patch(n).state == "operational" for n in wanted), timeout)

    def stats(self) -> dict[str, int]:
        """Data plane counters plus SYNC cycles, overruns, API drops and callback errors."""
        out = dict(self.dataplane.stats.snapshot())
        sync = self.sync
        out.update(sync_cycles=sync.cycle,
                   sync_overruns=sync.overruns if isinstance(sync, SyncProducer) else 0,
                   api_dropped=self.api_dropped, callback_errors=self.callback_errors)
        return out

    # -- data plane thread -------------------------------------------------------------

    def _on_frames(self, frames: list[ForceFrame]) -> None:
        for frame in frames:
            patch = self._patches.get(frame.patch)
            if patch is not None:
                self._account(patch, frame)
            self.fanout.publish(frame)

    def _account(self, patch: _Patch, frame: ForceFrame) -> None:
        previous = patch.last
        patch.last = frame
        patch.samples += 1
        if not frame.complete:
            patch.incomplete += 1
            return
        baseline = patch.baseline
        if baseline is None or baseline.time_constant_s is None:
            return
        raw = self.dataplane.raw_sample(frame.patch)
        if raw is None:
            return
        cycles = frame.cycle - previous.cycle if previous is not None else 1
        baseline.track(raw, frame.force_N, frame.valid,
                       max(cycles, 1) * self.config.sync_period_ms / 1000.0)

    # -- management plane --------------------------------------------------------------

    def _patch(self, node_id: int) -> _Patch:
        try:
            return self._patches[node_id]
        except KeyError:
            raise BusError(f"node {node_id} is not a configured patch") from None

    def _submit(self, job: Callable[[int], None], node_id: int) -> Future[None] | None:
        executor = self._executor
        if executor is None or not self._running:
            return None
        try:
            return executor.submit(job, node_id)
        except RuntimeError:  # shutting down
            return None

    def _request_setup(self, node_id: int, *, restart: bool) -> Future[None] | None:
        """(Re)configure a patch; returns the set-up job that will do it. With ``restart``
        (a boot-up: the node was reset) a set-up in progress starts over; without, a patch
        being configured or operational is left as it is."""
        with self._lock:
            patch = self._patches[node_id]
            if self._scanning:
                return None  # the scan finds it and configures it
            if not restart and patch.state in ("configuring", "operational"):
                return patch.job
            patch.generation += 1
            self._take_offline(patch, "configuring")
            if patch.queued:
                return patch.job
            patch.queued = True
            patch.job = self._submit(self._setup, node_id)
            return patch.job

    def _take_offline(self, patch: _Patch, state: str) -> None:
        if patch.channel is not None:
            self.dataplane.remove_channel(patch.config.node_id)
            patch.channel = None
        self._set_state(patch, state)

    def _set_state(self, patch: _Patch, state: str, error: str | None = None) -> None:
        with self._changed:
            patch.state, patch.error = state, error
            self._changed.notify_all()

    def _setup(self, node_id: int) -> None:
        patch = self._patches[node_id]
        with patch.sdo_lock:
            with self._lock:
                patch.queued = False
                generation = patch.generation
            try:
                identity = read_identity(patch.node.sdo)
                if identity.kind != "patch":
                    raise BusError(f"node {node_id} is not a patch: {_describe(identity)}")
                patch.node.nmt.send_command(NMT_PRE_OPERATIONAL)
                setup = setup_patch(patch.node, patch.config.mode,
                                    heartbeat_ms=self.config.heartbeat_ms)
                _warn_if_unlike_config(patch.config, setup.info)
                decoder, r0_ref = self._decoder(patch.config, setup)
            except (SdoError, can.CanError, SkinError) as err:
                with self._lock:
                    if generation == patch.generation and self._running:
                        self._set_state(patch, "failed", f"set-up failed: {err}")
                        logger.error("patch %d: set-up failed: %s", node_id, err)
                return
            with self._lock:
                if generation != patch.generation or not self._running:
                    return  # a newer request (e.g. a boot-up) is queued and starts over
                self._go_online(patch, setup, decoder, r0_ref)
                patch.node.nmt.send_command(NMT_START)
        logger.info("patch %d operational (%s, %s)", node_id, setup.mode,
                    patch.config.decoder)

    def _go_online(self, patch: _Patch, setup: PatchSetup, decoder: Decoder,
                   r0_ref: NDArray[np.float64]) -> None:
        p = setup.pillars
        drift = self.config.drift
        channel = PatchChannel(
            node_id=patch.config.node_id, codec=setup.codec, pillars=p,
            lsb_ohm=setup.info.lsb_ohm, decoder=decoder, force_node=patch.force_node,
            scale=np.ones((TAXELS_PER_PATCH, p)), masked=patch.masked,
            answer_order=patch.config.answer_order)
        patch.baseline = Baseline(
            r0_ref, setup.info.r0_ohm[:, :p], loaded_N=self.config.tare_threshold_N,
            time_constant_s=None if drift is None else drift.time_constant_s,
            contact_N=0.1 if drift is None else drift.contact_N,
            on_scale=lambda scale: setattr(channel, "scale", scale))
        patch.setup, patch.channel = setup, channel
        self.dataplane.add_channel(channel)
        self.monitor.judge(patch.config.node_id, True)
        self._set_state(patch, "operational")

    def _decoder(self, config: PatchConfig, setup: PatchSetup) -> tuple[Decoder,
                                                                         NDArray[np.float64]]:
        """The decoder of a patch, shared by every patch with the same decoder, model file
        and sensor constants (one batched decode call), and its zero-force resistances
        (9, P) for the patch's pillars."""
        constants = setup.info.constants
        key = (config.decoder, os.fspath(config.model or ""),
               constants if config.model is None else None)
        with self._lock:
            decoder = self._decoders.get(key)
            if decoder is None:
                if config.model is not None:
                    decoder = load_decoder(config.model)
                else:
                    try:
                        decoder = create_decoder(config.decoder, constants=constants)
                    except TypeError:  # a plug-in decoder without sensor constants
                        decoder = create_decoder(config.decoder)
                self._decoders[key] = decoder
        if isinstance(decoder, BaseDecoder):
            r0 = decoder.r0_for(setup.pillars)
        else:
            r0 = constants.nominal_resistance_ohm[: setup.pillars]
        r0_ref = np.broadcast_to(r0, (TAXELS_PER_PATCH, setup.pillars)).astype(np.float64)
        with self._lock:
            warm = (*key, setup.pillars) in self._warm
        if not warm:
            # A decoder may build tables on its first call (analytic z: the exact inverse
            # table): here, on a set-up thread, not in the data plane's first cycle.
            decoder.decode(r0_ref[None])
            with self._lock:
                self._warm.add((*key, setup.pillars))
        return decoder, r0_ref

    def _identify(self, node_id: int) -> None:
        identity: Identity | None
        try:
            with sdo_client(self.network, node_id,
                            timeout_s=self.config.sdo_timeout_ms / 1000.0) as client:
                identity = read_identity(client)
        except (SdoError, can.CanError):
            identity = None
        if identity is None:
            reason = "did not answer SDO 0x1018"
        elif identity.kind == "patch":
            reason = "a patch that is not in the config"
        else:
            reason = f"not managed ({_describe(identity)})"
        self._report_unknown(UnknownNode(node_id, identity, reason))

    # canopen notifier thread: record and hand on only.

    def _on_any_boot(self, node_id: int) -> None:
        # Patches: the heartbeat monitor reports their boot-ups. Force node-IDs: buses that
        # echo our own frames (udp_multicast) show our force nodes booting; a foreign node
        # at such an ID is caught by the scan at start (listen-only: another master's
        # force nodes, or the recorded host's).
        if node_id in self._patches or node_id in self._force_ids:
            return
        if node_id in self.config.other_nodes:
            return
        if self.listen_only:  # no SDO: reported as heard
            self._report_unknown(UnknownNode(node_id, None, "booted; not in the config "
                                             "(listen-only: not identified)"))
        elif not self._scanning:  # else the scan identifies it
            self._submit(self._identify, node_id)

    def _on_patch_boot(self, node_id: int) -> None:
        patch = self._patches[node_id]
        self._set_mask(patch, np.ones(TAXELS_PER_PATCH, dtype=bool), False)
        if self.listen_only:
            logger.info("patch %d booted", node_id)
            self._follow(node_id, "configuring")
            return
        logger.info("patch %d booted: configuring it", node_id)
        self.monitor.judge(node_id, False)  # a boot resets 0x1017 to the node's default
        self._request_setup(node_id, restart=True)

    def _on_return(self, node_id: int, state: int) -> None:
        if self.listen_only:
            self._follow(node_id, _state_name(state))
            return
        with self._lock:
            patch = self._patches[node_id]
            resume = (patch.state == "lost" and state == OPERATIONAL_STATE
                      and patch.setup is not None and patch.channel is None)
            if resume:
                assert patch.setup is not None
                decoder, r0_ref = self._decoder(patch.config, patch.setup)
                self._go_online(patch, patch.setup, decoder, r0_ref)
                logger.info("patch %d is back", node_id)
                return
        self._request_setup(node_id, restart=False)  # heard without a boot-up: configure it

    def _on_lost(self, node_id: int) -> None:
        with self._lock:
            patch = self._patches[node_id]
            if patch.state not in ("operational", "configuring", "stopped"):
                return
            patch.generation += 1  # a set-up in progress is void
            self._take_offline(patch, "lost")
        logger.warning("patch %d lost (no heartbeat for %.0f ms)", node_id,
                       self.monitor.lost_after_s * 1000)
        self._withdraw(patch)

    def _withdraw(self, patch: _Patch) -> None:
        """Publish one all-invalid sample: the last forces of a lost patch are void."""
        force = patch.force_node
        if self.listen_only or not force.transmitting:
            return
        reason = np.full(TAXELS_PER_PATCH, Reason.MISSING, dtype=np.uint8)
        for cob_id, payload in force.frames(np.zeros((TAXELS_PER_PATCH, 3)),
                                            np.zeros(TAXELS_PER_PATCH, bool), False,
                                            reason=reason):
            try:
                self.bus.send(TxMessage.data_frame(cob_id, payload))
            except can.CanError as err:
                logger.warning("force node %d: withdrawal not sent: %s", force.node_id, err)

    def _emcy_handler(self, patch: _Patch) -> Callable[[EmcyError], None]:
        consumer = patch.node.emcy

        def on_emcy(entry: EmcyError) -> None:
            with consumer.emcy_received:  # canopen logs every EMCY: keep the newest only
                if len(consumer.log) > 2 * EMCY_LOG_KEPT:
                    del consumer.log[:-EMCY_LOG_KEPT]
            taxel = entry.data[0] if entry.data else TAXELS_PER_PATCH
            if taxel >= TAXELS_PER_PATCH or entry.code not in (DEVICE_HARDWARE, ERROR_RESET):
                return
            which = np.zeros(TAXELS_PER_PATCH, dtype=bool)
            which[taxel] = True
            self._set_mask(patch, which, entry.code == DEVICE_HARDWARE)
        return on_emcy

    def _set_mask(self, patch: _Patch, taxels: NDArray[np.bool_], masked: bool) -> None:
        """Mask (or unmask) ``taxels`` for the samples completed from now on.

        The data plane reads a patch's mask when it publishes, which may be after the
        next cycle's frames arrived; so the samples already complete are published
        first, with the mask they were completed under: an EMCY (or boot-up) applies
        from its place on the bus, live and in a replay alike. Never under ``_lock``:
        publishing runs the force callbacks, which may call the API.
        """
        if bool(np.all(patch.masked[taxels] == masked)):
            return
        if self._dataplane is not None:
            self._dataplane.publish_pending()
        patch.masked[taxels] = masked

    # -- listen-only: follow what the bus shows ----------------------------------------

    def _follow(self, node_id: int, state: str) -> None:
        """The patch is now in ``state`` (its master's NMT command or its heartbeat says)."""
        with self._lock:
            patch = self._patches[node_id]
            if state != "operational":
                self._take_offline(patch, state)
            elif patch.channel is None and patch.setup is not None:
                decoder, r0_ref = self._decoder(patch.config, patch.setup)  # built at start
                self._go_online(patch, patch.setup, decoder, r0_ref)
                logger.info("patch %d operational", node_id)

    def _on_change(self, node_id: int, state: int) -> None:
        """A heartbeat entered or left OPERATIONAL (an NMT command we did not see)."""
        self._follow(node_id, _state_name(state))

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """An NMT command from any master. Start: the patch is decoded from now on, and if
        its heartbeat was not heard (lost, or not yet) it must come within ``lost_after``
        or the patch is lost. Stop, pre-operational, resets: a patch heard and not lost
        goes offline (a reset's boot-up follows)."""
        if len(data) != 2 or data[0] not in _NMT_COMMANDS:
            return
        state, target = _NMT_COMMANDS[data[0]], data[1]
        for node_id in (list(self._patches) if target == 0 else [target]):
            patch = self._patches.get(node_id)
            if patch is None:
                continue
            if state == "operational":
                if not self.monitor.alive(node_id):
                    self.monitor.expect(node_id)
            elif patch.state in ("absent", "lost"):
                continue
            self._follow(node_id, state)

    def _report_unknown(self, unknown: UnknownNode) -> None:
        with self._lock:
            self.unknown_nodes[unknown.node_id] = unknown
        logger.warning("node %d: %s; left alone", unknown.node_id, unknown.reason)
        if self.on_unknown is not None:
            try:
                self.on_unknown(unknown)
            except Exception:
                self.fanout.callback_errors += 1
                logger.exception("on_unknown callback failed")


def configured_info(patch: PatchConfig) -> PatchInfo:
    """What a patch holding the configured constants and R0 (default: ``DEFAULT_CONSTANTS``
    and its nominal R0) reports over SDO."""
    r0 = None if patch.r0_ohm is None else np.reshape(patch.r0_ohm, (-1, 3))
    return patch_info(patch.node_id, patch.constants or DEFAULT_CONSTANTS, r0)


def _warn_if_unlike_config(patch: PatchConfig, info: PatchInfo) -> None:
    """The config's constants and R0 (for listen-only use) against what the patch reports."""
    expected = configured_info(patch)
    if patch.constants is not None and expected.constants != info.constants:
        logger.warning("patch %d reports constants %s, the config says %s: decoding with the "
                       "patch's", patch.node_id, info.constants, expected.constants)
    if patch.r0_ohm is not None and not np.array_equal(expected.r0_ohm, info.r0_ohm):
        logger.warning("patch %d reports another R0 than the config's r0_ohm: decoding with "
                       "the patch's", patch.node_id)


def _state_name(state: int) -> str:
    """A patch's heartbeat state as a :class:`PatchHealth` state."""
    if state == OPERATIONAL_STATE:
        return "operational"
    return "stopped" if state == STOPPED_STATE else "configuring"


def _unsubscribe(network: canopen.Network, cob_id: int,
                 callback: Callable[[int, bytearray, float], None]) -> None:
    if callback in network.subscribers.get(cob_id, []):
        network.unsubscribe(cob_id, callback)


def _describe(identity: Identity) -> str:
    return (f"vendor 0x{identity.vendor:08X}, product {identity.product}, "
            f"revision 0x{identity.revision:08X}, serial {identity.serial}")


def _set_tpdo_cob_ids(force: ForceNode, cob_ids: tuple[int, ...]) -> None:
    """Move the force node's TPDOs to the configured COB-IDs (CiA 301: invalidate first)."""
    for n, cob_id in enumerate(cob_ids):
        index = 0x1800 + n
        old = int(force.store.value(index, 1))
        force.store.set_data(index, 1, (old | 0x8000_0000).to_bytes(4, "little"))
        force.store.set_data(index, 1, cob_id.to_bytes(4, "little"))
