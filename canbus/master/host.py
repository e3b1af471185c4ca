"""The host manager: the CANopen master of the skin's patches and the publisher of their forces.

::

    with HostManager(bus, load_host_config("host.toml")) as host:
        host.on_forces(print)                      # callback(frame: ForceFrame)
        for frame in host.frames(timeout=1.0):     # or iterate
            ...
        host.health()                              # {node_id: PatchHealth}
        host.tare(1)                               # re-zero patch 1 (refused while loaded)

One facade, two policies. :class:`HostManager` owns what every host has: one
:class:`~canbus.master.buslink.BusLink` per bus (a canopen ``Network``, a notifier, a
:class:`~canbus.master.dataplane.DataPlane` that turns its patches' PDOs into forces, a
heartbeat consumer), one record per configured patch, the decoders, and the API.
What it does with the patches is its policy's:

- :class:`~canbus.master.active.ActiveMaster` (the default) discovers the patches (boot-up,
  canopen's SDO scan, 0x1018), configures them by SDO, starts them by NMT, produces SYNC on
  each patch bus (or, with ``sync = "external"``, follows the SYNC another master
  produces), re-configures a patch that boots again;
- :class:`~canbus.master.follower.ListenOnly` (``listen_only``) transmits nothing: it
  decodes what another master runs (or a recording ``skin replay`` sends), following the
  NMT commands, boot-ups, heartbeats and SYNCs on the bus.

Several buses: ``HostManager({"skin-a": bus_a, "arm": bus_b}, config)`` with the config's
``[[buses]]``; each patch is on its bus, each force node on its own (``force_bus``). A
``canopen.Network`` the caller already runs may stand for a bus: the host joins it.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import Any, Self, cast

import can
import canopen
import numpy as np
from canopen.emcy import EmcyError
from numpy.typing import NDArray

from canbus.master.active import ActiveMaster
from canbus.master.baseline import Baseline, PatchLoadedError
from canbus.master.buslink import BusLink
from canbus.master.contactconfig import patch_contact, take_pitch
from canbus.master.dataplane import DataPlane, ForceFrame, PatchChannel
from canbus.master.decoders import DecoderCache
from canbus.master.discovery import UnknownNode
from canbus.master.events import EmcyEvent, EventCallback, EventHooks, StateEvent
from canbus.master.fanout import FrameCallback, FrameFanout
from canbus.master.follower import ListenOnly
from canbus.master.forcenode import ForceNode
from canbus.master.frame_kinds import bus_cob_ids
from canbus.master.hostconfig import HostConfig, load_host_config
from canbus.master.lss_assign import Assignment, assign_at_start, force_node_store
from canbus.master.patch_setup import PatchSetup
from canbus.master.records import STATES, PatchHealth, PatchRecord
from canbus.master.sync_producer import SyncFollower, SyncProducer
from canbus.master.taxel_log import TaxelLog
from canbus.od import load_od
from skin.constants import TAXELS_PER_PATCH
from skin.errors import BusError

__all__ = ["STATES", "ForceFrame", "HostManager", "PatchHealth", "PatchLoadedError"]

logger = logging.getLogger(__name__)

EMCY_LOG_KEPT = 256
ANSWER_POLL_S = 0.0005  # on stop, how often the last cycle's answers are looked at
"""EMCYs of a patch kept in canopen's ``EmcyConsumer.log`` (trimmed to this many once it
holds twice as many): a long-running host with a flapping taxel must not grow without
bound. ``emcy.active`` is canopen's own, cleared by each error reset."""
DEVICE_HARDWARE, ERROR_RESET = 0x5000, 0x0000
EMCY_TEXT = {DEVICE_HARDWARE: "taxel fault (device hardware)", ERROR_RESET: "taxel recovered"}
TAXEL_FAULTS = {1: "open", 2: "short", 3: "saturated"}  # 0x2004 two bits per pillar

Buses = can.BusABC | canopen.Network | Mapping[str, can.BusABC | canopen.Network]


class HostManager:
    """Discovers, configures, starts and watches the patches of ``config`` on its buses.

    ``bus``: one python-can bus (or a connected ``canopen.Network``) for a config with one
    bus, or a mapping from the config's bus names to them. The caller owns the buses (they
    are not shut down on stop). ``on_unknown`` is called with an
    :class:`~canbus.master.discovery.UnknownNode` for every node the host does not manage;
    the host never writes to such a node. ``listen_only`` (default: ``config.listen_only``):
    decode what another master runs and send nothing. ``clock`` (default: real time,
    checked by each heartbeat consumer's thread) times the heartbeats and leaves the
    checks to the caller (``link.monitor.check()``): a recording's clock when one is
    decoded offline (``canbus.offline.decode``).
    """

    def __init__(self, bus: Buses, config: HostConfig, *,
                 on_unknown: Callable[[UnknownNode], None] | None = None,
                 listen_only: bool | None = None,
                 clock: Callable[[], float] | None = None) -> None:
        config = config.check()
        if listen_only is not None:
            config = replace(config, listen_only=listen_only)
        self.config = config
        self.listen_only = config.listen_only
        self.on_unknown = on_unknown
        self.unknown_nodes: dict[int, UnknownNode] = {}
        self.decoders = DecoderCache()
        self.fanout = FrameFanout()
        self.events = EventHooks()
        self.taxel_log = TaxelLog()
        self._lock = threading.RLock()
        self._changed = threading.Condition(self._lock)  # notified on every state change
        self._running = False
        self.executor: ThreadPoolExecutor | None = None
        self.links: dict[str, BusLink] = {}
        for name, given in _by_name(bus, config).items():
            self.links[name] = BusLink(
                config.bus(name), given, heartbeat_ms=config.heartbeat_ms,
                on_boot=self._on_patch_boot, on_lost=self._on_lost, on_return=self._on_return,
                on_change=self._on_change if self.listen_only else None,
                on_any_boot=self._on_any_boot, clock=clock)
        self.patches: dict[int, PatchRecord] = {}
        for patch in config.patches:
            node = canopen.RemoteNode(patch.node_id, load_od("skin-patch", patch.node_id))
            node.sdo.RESPONSE_TIMEOUT = config.sdo_timeout_ms / 1000.0
            force = ForceNode(patch.force_node, patch.node_id,
                              heartbeat_ms=config.force_heartbeat_ms,
                              contact=patch_contact(patch, config),
                              nv=force_node_store(config.state_dir, patch.force_node))
            record = PatchRecord(patch, self.links[patch.bus], self.links[patch.force_bus],
                                 node, force)
            self.patches[patch.node_id] = record
            node.emcy.add_callback(self._emcy_handler(record))
        self.force_ids = {p.force_node: p.node_id for p in config.patches}
        self.lss_assignments: list[Assignment] = []
        self.policy: ActiveMaster | ListenOnly = \
            ListenOnly(self) if self.listen_only else ActiveMaster(self)

    @classmethod
    def from_config(cls, path: str | os.PathLike[str], bus: Buses, **kwargs: Any) -> Self:
        """A host for the config file at ``path`` (see ``examples/host.toml``)."""
        return cls(bus, load_host_config(path), **kwargs)

    # -- lifecycle ---------------------------------------------------------------------

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> None:
        """Start every bus and the policy: discover and configure the patches present, boot
        the force nodes, start SYNC (listen-only: start following).

        Returns when the patches that answered the scan are configured (or failed). Raises
        :class:`~skin.errors.BusError` if a node on a bus would collide with a force node;
        the host is then stopped again.
        """
        if self._running:
            raise BusError("the host is already running")
        self._running = True
        try:
            self.policy.prepare()
            self.policy.subscribe()  # before any notifier runs: frames queued count too
            window_s = self.config.sync_window_ms / 1000.0
            patch_buses = {p.link.name for p in self.patches.values()}
            for link in self.links.values():
                if link.name in patch_buses:
                    link.dataplane = DataPlane(link.bus, sync_window_s=window_s)
                    link.dataplane.bus_traffic = bus_cob_ids(self.config, link.name)
                    link.dataplane.subscribe(self._on_frames)
            for patch in self.patches.values():  # one sample per SYNC from the first
                self.add_placeholder(patch, patch.setup or self.policy.planned(patch))
            for link in self.links.values():
                dataplane = link.dataplane
                follower = (SyncFollower(dataplane.on_sync)
                            if dataplane is not None and self.config.sync_following else None)
                link.listen(dataplane, follower)
            if not self.listen_only:  # node-IDs by serial number (LSS) before the scan
                self.lss_assignments = assign_at_start(self.config, self.patches)
            self.policy.start()
        except BaseException:
            self.stop()
            raise

    def stop(self) -> None:
        """Stop SYNC, publish what is pending, stop consumers and force nodes, end iterators."""
        if not self._running:
            return
        self._running = False
        for link in self.links.values():
            link.stop_sync()
        if any(link.sync is not None and link.sync.cycle for link in self.links.values()):
            self._await_last_answers()
        for link in self.links.values():
            if link.dataplane is not None:
                link.dataplane.flush()
        self.policy.stop()
        for link in self.links.values():
            link.close()
        self.taxel_log.flush()
        self.fanout.close()

    def _await_last_answers(self) -> None:
        """The last cycle's answers: until every patch has answered it, for at most a SYNC
        period (a frame stamped inside the window may be handed over a little after it, on
        a busy machine or a bus that keeps time)."""
        dataplanes = [link.dataplane for link in self.links.values()
                      if link.dataplane is not None]
        deadline = time.monotonic() + max(self.config.sync_window_ms,
                                          self.config.sync_period_ms) / 1000.0
        while not all(dp.answered() for dp in dataplanes) and time.monotonic() < deadline:
            time.sleep(ANSWER_POLL_S)

    @property
    def running(self) -> bool:
        return self._running

    # -- the public API ----------------------------------------------------------------

    @property
    def bus(self) -> can.BusABC:
        """The bus of a one-bus host."""
        return self._only_link().bus

    @property
    def network(self) -> canopen.Network:
        """The canopen Network of a one-bus host."""
        return self._only_link().network

    @property
    def dataplane(self) -> DataPlane:
        """The data plane of a one-bus host's current (or last) run."""
        dataplane = self._only_link().dataplane
        if dataplane is None:
            raise BusError("the host has not been started")
        return dataplane

    @property
    def sync(self) -> SyncProducer | SyncFollower:
        """The SYNC producer (following: follower) of a one-bus host's current (or last) run."""
        sync = self._only_link().sync
        if sync is None:
            raise BusError("the host has not been started")
        return sync

    def _only_link(self) -> BusLink:
        if len(self.links) != 1:
            raise BusError(f"the host has {len(self.links)} buses: use host.links[name]")
        return next(iter(self.links.values()))

    def on_forces(self, callback: FrameCallback) -> None:
        """Call ``callback(frame)`` for every force frame, on a data plane's thread.

        Keep it short: the next patch's frames wait for it. An exception is logged with
        its traceback and counted in :attr:`callback_errors`; the other callbacks run.
        """
        self.fanout.add_callback(callback)

    def remove_callback(self, callback: FrameCallback) -> None:
        self.fanout.remove_callback(callback)

    def on_event(self, callback: EventCallback) -> None:
        """Call ``callback(event)`` for every patch state change
        (:class:`~canbus.master.events.StateEvent`) and EMCY
        (:class:`~canbus.master.events.EmcyEvent`), on the thread that saw it; keep it short.
        """
        self.events.add(callback)

    def remove_event_callback(self, callback: EventCallback) -> None:
        self.events.remove(callback)

    @property
    def callback_errors(self) -> int:
        """Exceptions raised by force, event and ``on_unknown`` callbacks (logged)."""
        return self.fanout.callback_errors + self.events.errors

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
            for node_id, p in self.patches.items():
                out[node_id] = PatchHealth(
                    state=p.state, lost=p.state == "lost",
                    faulty_taxels=tuple(int(k) for k in np.flatnonzero(p.masked)),
                    last_heartbeat_unix_s=p.link.monitor.last_heartbeat(node_id),
                    samples=p.samples, incomplete=p.incomplete, error=p.error,
                    bus=p.link.name)
        return out

    def tare(self, node_id: int) -> None:
        """Re-zero patch ``node_id`` at its last complete sample.

        Raises :class:`~canbus.master.baseline.PatchLoadedError` while any taxel of the
        patch reads more than ``host.tare_threshold_N`` (or before its first sample), and
        :class:`~skin.errors.BusError` if the patch is not operational.
        """
        with self._lock:
            patch = self.patch(node_id)
            channel = patch.channel
            if patch.state != "operational" or channel is None:
                raise BusError(f"patch {node_id} is {patch.state}: nothing to tare")
            dataplane = patch.link.dataplane
        assert dataplane is not None
        dataplane.tare(node_id)
        logger.info("patch %d tared", node_id)

    def wait_operational(self, node_ids: list[int] | None = None, timeout: float = 10.0) -> bool:
        """Wait until the patches (default: all configured) are operational; False on
        time-out."""
        wanted = list(self.patches) if node_ids is None else node_ids
        with self._changed:
            return self._changed.wait_for(
                lambda: all(self.patch(n).state == "operational" for n in wanted), timeout)

    def stats(self) -> dict[str, int]:
        """Data plane counters summed over the buses, plus SYNC cycles (the most of any bus),
        overruns, API drops and callback errors."""
        out: dict[str, int] = {}
        cycles = overruns = 0
        for link in self.links.values():
            if link.dataplane is not None:
                for key, value in link.dataplane.stats.snapshot().items():
                    out[key] = out.get(key, 0) + value
            if link.sync is not None:
                cycles = max(cycles, link.sync.cycle)
                overruns += link.sync.overruns if isinstance(link.sync, SyncProducer) else 0
        out.update(sync_cycles=cycles, sync_overruns=overruns, api_dropped=self.api_dropped,
                   callback_errors=self.callback_errors)
        return out

    def bus_stats(self) -> dict[str, dict[str, Any]]:
        """Per bus: its data plane's counters, SYNC cycles and overruns, and what the bus
        itself counts when it can (the timed bus's wire statistics)."""
        out: dict[str, dict[str, Any]] = {}
        for name, link in self.links.items():
            entry: dict[str, Any] = dict(link.dataplane.stats.snapshot()
                                         if link.dataplane is not None else {})
            sync = link.sync
            entry["sync_cycles"] = sync.cycle if sync is not None else 0
            entry["sync_overruns"] = sync.overruns if isinstance(sync, SyncProducer) else 0
            entry["patches"] = sorted(n for n, p in self.patches.items() if p.link is link)
            entry["force_nodes"] = sorted(p.config.force_node for p in self.patches.values()
                                          if p.force_link is link)
            wire = getattr(link.bus, "wire_stats", None)
            if callable(wire):
                entry["wire"] = _plain(wire())
            out[name] = entry
        return out

    # -- what both policies use --------------------------------------------------------

    def patch(self, node_id: int) -> PatchRecord:
        try:
            return self.patches[node_id]
        except KeyError:
            raise BusError(f"node {node_id} is not a configured patch") from None

    def set_state(self, patch: PatchRecord, state: str, error: str | None = None) -> None:
        with self._changed:
            previous = patch.state
            if previous != state:
                logger.info("patch %d: %s -> %s%s", patch.node_id, patch.state, state,
                            f" ({error})" if error else "")
            patch.state, patch.error = state, error
            self._changed.notify_all()
        if previous != state:
            self.events.emit(StateEvent(patch.node_id, patch.link.name, state, previous, error,
                                        time.time()))

    def take_offline(self, patch: PatchRecord, state: str) -> None:
        """Stop decoding the patch: from now on its samples are all-invalid (``MISSING``),
        one per SYNC, so that no consumer keeps its last forces and every cycle counts."""
        dataplane = patch.link.dataplane
        if patch.channel is not None and dataplane is not None:
            dataplane.set_online(patch.node_id, False)
            patch.channel = None
        self.set_state(patch, state)

    def add_placeholder(self, patch: PatchRecord, setup: PatchSetup) -> None:
        """An offline channel for a patch not decoded yet: its all-invalid sample per SYNC."""
        dataplane = patch.link.dataplane
        assert dataplane is not None
        decoder, _ = self.decoders.get(patch.config, setup)
        dataplane.add_channel(PatchChannel(
            node_id=patch.node_id, codec=setup.codec, pillars=setup.pillars,
            lsb_ohm=setup.info.lsb_ohm, decoder=decoder, force_node=patch.force_node,
            masked=patch.masked, answer_order=patch.config.answer_order), online=False)

    def go_online(self, patch: PatchRecord, setup: PatchSetup) -> None:
        """Decode the patch from now on (lock held by the caller)."""
        decoder, r0_ref = self.decoders.get(patch.config, setup)
        p = setup.pillars
        drift = self.config.drift
        baseline = Baseline(
            r0_ref, setup.info.r0_ohm[:, :p], loaded_N=self.config.tare_threshold_N,
            time_constant_s=None if drift is None else drift.time_constant_s,
            contact_N=0.1 if drift is None else drift.contact_N)
        channel = PatchChannel(
            node_id=patch.node_id, codec=setup.codec, pillars=p, lsb_ohm=setup.info.lsb_ohm,
            decoder=decoder, force_node=patch.force_node, masked=patch.masked,
            baseline=baseline, answer_order=patch.config.answer_order)
        patch.setup, patch.channel = setup, channel
        take_pitch(patch.force_node.contact, setup.info.constants)
        dataplane = patch.link.dataplane
        assert dataplane is not None, "the patch's bus is listening"
        dataplane.add_channel(channel)
        patch.link.monitor.judge(patch.node_id, True)
        self.set_state(patch, "operational")

    def set_mask(self, patch: PatchRecord, taxels: NDArray[np.bool_], masked: bool) -> None:
        """Mask (or unmask) ``taxels`` for the samples completed from now on.

        The data plane reads a patch's mask when it publishes, which may be after the
        next cycle's frames arrived; so the samples already complete are published
        first, with the mask they were completed under: an EMCY (or boot-up) applies
        from its place on the bus, live and in a replay alike. Never under ``_lock``:
        publishing runs the force callbacks, which may call the API.
        """
        if bool(np.all(patch.masked[taxels] == masked)):
            return
        dataplane = patch.link.dataplane
        if dataplane is not None:
            dataplane.publish_pending()
        patch.masked[taxels] = masked

    def report_unknown(self, unknown: UnknownNode) -> None:
        with self._lock:
            self.unknown_nodes[unknown.node_id] = unknown
        logger.warning("node %d: %s; left alone", unknown.node_id, unknown.reason)
        if self.on_unknown is not None:
            try:
                self.on_unknown(unknown)
            except Exception:
                self.fanout.callback_errors += 1
                logger.exception("on_unknown callback failed")

    # -- data plane threads ------------------------------------------------------------

    def _on_frames(self, frames: list[ForceFrame]) -> None:
        for frame in frames:
            patch = self.patches.get(frame.patch)
            if patch is not None:
                patch.last = frame
                patch.samples += 1
                patch.incomplete += not frame.complete
            self.taxel_log.note(frame)
            self.fanout.publish(frame)

    # -- bus threads: record and hand on ------------------------------------------------

    def _on_patch_boot(self, node_id: int) -> None:
        patch = self.patches.get(node_id)
        if patch is None:
            return
        self.set_mask(patch, np.ones(TAXELS_PER_PATCH, dtype=bool), False)
        self.policy.on_patch_boot(patch)

    def _on_return(self, node_id: int, state: int) -> None:
        patch = self.patches.get(node_id)
        if patch is not None:
            self.policy.on_return(patch, state)

    def _on_lost(self, node_id: int) -> None:
        patch = self.patches.get(node_id)
        if patch is not None:
            self.policy.on_lost(patch)

    def _on_change(self, node_id: int, state: int) -> None:
        patch = self.patches.get(node_id)
        if patch is not None:
            self.policy.on_change(patch, state)

    def _on_any_boot(self, link: BusLink, node_id: int) -> None:
        # Patches: the heartbeat monitor reports their boot-ups. Force node-IDs: buses that
        # echo our own frames (udp_multicast) show our force nodes booting; a foreign node
        # at such an ID is caught by the scan at start.
        if node_id in self.patches or node_id in self.force_ids:
            return
        if node_id in self.config.other_nodes:
            return
        self.policy.on_unknown_boot(link, node_id)

    def _emcy_handler(self, patch: PatchRecord) -> Callable[[EmcyError], None]:
        consumer = patch.node.emcy

        def on_emcy(entry: EmcyError) -> None:
            with consumer.emcy_received:  # canopen logs every EMCY: keep the newest only
                if len(consumer.log) > 2 * EMCY_LOG_KEPT:
                    del consumer.log[:-EMCY_LOG_KEPT]
            taxel = entry.data[0] if entry.data else TAXELS_PER_PATCH
            _log_emcy(patch.node_id, entry)
            if taxel < TAXELS_PER_PATCH and entry.code in (DEVICE_HARDWARE, ERROR_RESET):
                which = np.zeros(TAXELS_PER_PATCH, dtype=bool)
                which[taxel] = True
                self.set_mask(patch, which, entry.code == DEVICE_HARDWARE)
            # after the mask: the samples completed before the EMCY went out first
            self.events.emit(EmcyEvent(patch.node_id, patch.link.name, entry.code,
                                       entry.register, bytes(entry.data), time.time()))
        return on_emcy


def _log_emcy(node_id: int, entry: EmcyError) -> None:
    text = EMCY_TEXT.get(entry.code, entry.get_desc() or "error")
    data = bytes(entry.data)
    if entry.code == DEVICE_HARDWARE and len(data) >= 2:
        status = data[1]
        pillars = ", ".join(f"{axis} {TAXEL_FAULTS[status >> (2 * k) & 3]}"
                            for k, axis in enumerate("zxy") if status >> (2 * k) & 3)
        logger.warning("patch %d: EMCY 0x%04X %s: taxel %d (%s); masked", node_id,
                       entry.code, text, data[0], pillars or "status 0")
    elif entry.code == ERROR_RESET and data:
        logger.info("patch %d: EMCY 0x%04X %s: taxel %d", node_id, entry.code, text, data[0])
    else:
        logger.warning("patch %d: EMCY 0x%04X %s (register 0x%02X, data %s)", node_id,
                       entry.code, text, entry.register, data.hex())


def _by_name(bus: Buses, config: HostConfig) -> dict[str, can.BusABC | canopen.Network]:
    names = [b.name for b in config.buses]
    if isinstance(bus, can.BusABC | canopen.Network):
        if len(names) != 1:
            raise BusError(f"the config has {len(names)} buses ({', '.join(names)}): give the "
                           "host a mapping from each name to its bus")
        return {names[0]: bus}
    given = dict(cast(Mapping[str, can.BusABC | canopen.Network], bus))
    if sorted(given) != sorted(names):
        raise BusError(f"the config's buses are {', '.join(names)}; given "
                       f"{', '.join(given) or 'none'}")
    return given


def _plain(value: Any) -> Any:
    """A dataclass (a bus's statistics) as plain JSON-able values."""
    import dataclasses

    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {k: _plain(v) for k, v in dataclasses.asdict(value).items()}
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value

