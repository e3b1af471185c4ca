"""The host manager: the CANopen master of the skin's patches and the publisher of their forces.

::

    with HostManager(bus, load_host_config("host.toml")) as host:
        host.on_forces(print)                      # callback(frame: ForceFrame)
        host.on_raw_samples(print)                 # callback(samples: list[RawSample])
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

Each patch's state is derived in one place (:mod:`canbus.master.patchstate`) from what
the policy records (heartbeats, boot-ups, NMT, set-up results); the facade puts the
patch's channel online or offline with each change. The policies get the narrow
:class:`~canbus.master.policy.HostParts`, never the facade.

Several buses: ``HostManager({"skin-a": bus_a, "arm": bus_b}, config)`` with the config's
``[[buses]]``; each patch is on its bus, each force node on its own (``force_bus``). A
``canopen.Network`` the caller already runs may stand for a bus: the host joins it. A
bus given as a :class:`canbus.busio.ResilientBus` is opened again when it keeps failing;
:meth:`HostManager.bus_gone` says when one is gone for good.
"""


from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from typing import Any, Self

import can
import canopen
import numpy as np
from canopen.emcy import EmcyError

from canbus.master.active import ActiveMaster
from canbus.master.baseline import PatchLoadedError
from canbus.master.buslink import BusLink
from canbus.master.contactconfig import patch_contact
from canbus.master.dataplane import DataPlane, ForceFrame
from canbus.master.decoders import DecoderCache
from canbus.master.discovery import UnknownNode, haltable_sdo, log_unknown
from canbus.master.emcy import BoundedEmcyConsumer
from canbus.master.events import EmcyEvent, EventCallback, EventHooks, StateEvent
from canbus.master.fanout import FrameCallback, FrameFanout
from canbus.master.follower import ListenOnly
from canbus.master.forcenode import ForceNode
from canbus.master.frame_kinds import bus_cob_ids
from canbus.master.hostconfig import HostConfig, PatchConfig, load_host_config
from canbus.master.hoststats import Buses, buses_by_name, per_bus_stats, summed_stats
from canbus.master.lss_assign import Assignment, assign_at_start, force_node_store
from canbus.master.patchchannels import PatchChannels
from canbus.master.patchstate import STATES, Facts, PatchStates, Transition
from canbus.master.policy import HostParts, Policy
from canbus.master.rawsample import RawSubscriber
from canbus.master.records import PatchHealth, PatchRecord
from canbus.master.sync_producer import SyncFollower, SyncProducer
from canbus.master.taxel_log import TaxelLog
from canbus.od import load_od
from canbus.rxfilter import echoes_own_frames
from skin.errors import BusError

__all__ = ("STATES", "ForceFrame", "HostManager", "PatchHealth", "PatchLoadedError")

logger = logging.getLogger(__name__)

ANSWER_POLL_S = 0.0005  # on stop, how often the last cycle's answers are looked at


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
        self._raw_subscribers: tuple[RawSubscriber, ...] = ()
        self.events = EventHooks()
        self.taxel_log = TaxelLog()
        self._lifecycle = threading.RLock()  # start and stop, one at a time
        self._stopping = threading.Event()  # a stop was asked for: start's waits end
        self._running = threading.Event()
        self.links: dict[str, BusLink] = {}
        for name, given in buses_by_name(bus, config).items():
            self.links[name] = BusLink(
                config.bus(name), given, heartbeat_ms=config.heartbeat_ms,
                on_boot=self._on_patch_boot, on_lost=self._on_lost, on_return=self._on_return,
                on_change=self._on_change if self.listen_only else None,
                on_any_boot=self._on_any_boot, clock=clock)
        self.patches: dict[int, PatchRecord] = {}
        self.channels = PatchChannels(config, self.patches, self.decoders, self._running)
        for patch in config.patches:
            self.patches[patch.node_id] = record = self._record(patch)
            record.node.emcy.add_callback(self.channels.emcy_handler(record))
            record.node.emcy.add_callback(self._emcy_event(record))  # after the mask
        self.force_ids = {p.force_node: p.node_id for p in config.patches}
        self.lss_assignments: list[Assignment] = []
        self.states = PatchStates({n: p.link.monitor for n, p in self.patches.items()},
                                  listen_only=self.listen_only, apply=self._on_transition)
        parts = HostParts(config, self.patches, self.links, self.force_ids, self.decoders,
                          self.states, self._stopping, self.report_unknown, self.tare)
        self.policy: Policy = ListenOnly(parts) if self.listen_only else ActiveMaster(parts)

    def _record(self, patch: PatchConfig) -> PatchRecord:
        node = canopen.RemoteNode(patch.node_id, load_od("skin-patch", patch.node_id))
        haltable_sdo(node).RESPONSE_TIMEOUT = self.config.sdo_timeout_ms / 1000.0
        node.emcy = BoundedEmcyConsumer()
        force = ForceNode(patch.force_node, patch.node_id,
                          heartbeat_ms=self.config.force_heartbeat_ms,
                          contact=patch_contact(patch, self.config),
                          nv=force_node_store(self.config.state_dir, patch.force_node))
        return PatchRecord(patch, self.links[patch.bus], self.links[patch.force_bus], node,
                           force)

    def _on_transition(self, transition: Transition, facts: Facts) -> None:
        """A patch changed state (the states' lock held): its channel follows, then the
        event hooks hear it."""
        self.channels.apply(transition, facts)
        link = self.patches[transition.node_id].link.name
        self.events.emit(StateEvent(transition.node_id, link, transition.new, transition.old,
                                    transition.reason, transition.time))

    def _emcy_event(self, patch: PatchRecord) -> Callable[[EmcyError], None]:
        def on_emcy(entry: EmcyError) -> None:
            self.events.emit(EmcyEvent(patch.node_id, patch.link.name, entry.code,
                                       entry.register, bytes(entry.data), time.time()))
        return on_emcy

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

        Returns when the patches that answered the scan are configured (or their first
        set-up failed: it is retried while they beat), or at once when :meth:`stop` is
        called meanwhile (from another thread, or a signal's handler). Raises
        :class:`~skin.errors.BusError` if a node on a bus would collide with a force node;
        the host is then stopped again.
        """
        with self._lifecycle:
            if self._running.is_set():
                raise BusError("the host is already running")
            self._running.set()
            self._stopping.clear()
            try:
                self._start()
            except BaseException:
                self._stop()
                raise

    def _start(self) -> None:
        self.policy.prepare()
        self.policy.subscribe()  # before any notifier runs: frames queued count too
        # A listen-only host takes a cycle's frames by their place between two SYNCs on the
        # bus: a replay keeps that order, not the time between frames the window judges.
        window_s = 0.0 if self.listen_only else self.config.sync_window_ms / 1000.0
        patch_buses = {p.link.name for p in self.patches.values()}
        for link in self.links.values():
            if link.name in patch_buses:
                link.dataplane = DataPlane(link.bus, sync_window_s=window_s)
                link.dataplane.bus_traffic = bus_cob_ids(self.config, link.name)
                link.dataplane.sync_echo = echoes_own_frames(link.bus) and \
                    self.config.sync_counter and not self.config.sync_following
                link.dataplane.subscribe(self._on_frames)
                for raw in self._raw_subscribers:
                    link.dataplane.subscribe_raw(raw)
        for patch in self.patches.values():  # one sample per SYNC from the first
            self.channels.placeholder(patch, self.policy.planned(patch))
        self.states.announce()
        for link in self.links.values():
            dataplane = link.dataplane
            follower = (SyncFollower(dataplane.on_sync)
                        if dataplane is not None and self.config.sync_following else None)
            link.listen(dataplane, follower)
        if not self.listen_only:  # node-IDs by serial number (LSS) before the scan
            self.lss_assignments = assign_at_start(self.config, self.patches)
        self.policy.start()

    def stop(self) -> None:
        """Stop SYNC, publish what is pending, stop consumers and force nodes, end iterators.

        Prompt whatever the host is doing: a start in progress (scan, set-ups) ends at
        once, SDO transfers are cut short; what waits is the last cycle's answers (one
        SYNC period at most) and publishing what is in flight. Any thread may call it."""
        self._stopping.set()
        with self._lifecycle:
            self._stop()

    def _stop(self) -> None:
        if not self._running.is_set():
            return
        self._running.clear()
        self._stopping.set()
        # Each step on its own: a stop (a signal) may come at any point of a start, and
        # what one step finds half done must not leave the others undone.
        for link in self.links.values():
            _step("stopping SYNC", link.stop_sync)
        if any(link.sync is not None and link.sync.cycle for link in self.links.values()):
            self._await_last_answers()
        for link in self.links.values():
            if link.dataplane is not None:
                _step("publishing the last samples", link.dataplane.flush)
        _step("stopping the policy", self.policy.stop)
        for link in self.links.values():
            _step(f"closing bus {link.name!r}", link.close)
        self.taxel_log.flush()
        self.channels.emcy_log.flush()
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
        return self._running.is_set()

    def bus_gone(self) -> str | None:
        """Why receiving ended for good on a bus (a :class:`canbus.busio.ResilientBus`
        that could not be opened again); None while every bus is heard. The host cannot
        hear its patches then: a service should stop (``skin run`` exits with status 1)."""
        for link in self.links.values():
            if link.gone is not None:
                return link.gone
        return None

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

    def on_raw_samples(self, callback: RawSubscriber) -> None:
        """Call ``callback(samples)`` with each published batch's raw samples (each patch's
        resistances as it sent them, before the host's scale and decoder:
        :class:`~canbus.master.rawsample.RawSample`), on a data plane's thread; keep it
        short, as :meth:`on_forces`'s. An exception is logged and counted in its bus's data
        plane counters (:meth:`bus_stats`, ``callback_errors``)."""
        with self._lifecycle:
            self._raw_subscribers = (*self._raw_subscribers, callback)
            for link in self.links.values():
                if link.dataplane is not None:
                    link.dataplane.subscribe_raw(callback)

    def remove_raw_callback(self, callback: RawSubscriber) -> None:
        with self._lifecycle:
            self._raw_subscribers = tuple(c for c in self._raw_subscribers if c != callback)
            for link in self.links.values():
                if link.dataplane is not None:
                    link.dataplane.unsubscribe_raw(callback)

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
                                   self._running.is_set)

    def health(self) -> dict[int, PatchHealth]:
        """Every configured patch's state, by node-ID."""
        out = {}
        for node_id, p in self.patches.items():
            view = self.states.view(node_id)
            out[node_id] = PatchHealth(
                state=view.state, lost=view.state == "lost",
                faulty_taxels=tuple(int(k) for k in np.flatnonzero(p.masked)),
                last_heartbeat_unix_s=p.link.monitor.last_heartbeat(node_id),
                samples=p.samples, incomplete=p.incomplete, error=view.reason,
                bus=p.link.name, setup_failures=view.setup_failures,
                state_changes=view.changes,
                history=tuple((t.time, t.new, t.reason) for t in view.history),
                emcys=getattr(p.node.emcy, "received", 0), force_conflict=p.force_conflict)
        return out

    def tare(self, node_id: int) -> None:
        """Re-zero patch ``node_id`` at its last complete sample.

        Raises :class:`~canbus.master.baseline.PatchLoadedError` while any taxel of the
        patch reads more than ``host.tare_threshold_N`` (or before its first sample), and
        :class:`~skin.errors.BusError` if the patch is not operational.
        """
        patch = self.patch(node_id)
        with self.states.changed:
            state = self.states.state(node_id)
            if state != "operational" or patch.channel is None:
                raise BusError(f"patch {node_id} is {state}: nothing to tare")
            dataplane = patch.link.dataplane
        assert dataplane is not None
        dataplane.tare(node_id)
        logger.info("patch %d tared", node_id)

    def wait_operational(self, node_ids: list[int] | None = None, timeout: float = 10.0) -> bool:
        """Wait until the patches (default: all configured) are operational; False on
        time-out."""
        wanted = list(self.patches) if node_ids is None else node_ids
        for node_id in wanted:
            self.patch(node_id)
        return self.states.wait_for(wanted, "operational", timeout)

    def stats(self) -> dict[str, int]:
        """Data plane counters summed over the buses, plus SYNC cycles (the most of any bus),
        overruns, API drops and callback errors."""
        return summed_stats(self.links.values(), api_dropped=self.api_dropped,
                            callback_errors=self.callback_errors)

    def bus_stats(self) -> dict[str, dict[str, Any]]:
        """Per bus: its data plane's counters, SYNC cycles and overruns, what receiving
        survived (``receive``: errors, re-opens, the last error, ``gone``), and what the bus
        itself counts when it can (the timed bus's wire statistics)."""
        return per_bus_stats(self.links, self.patches.values())

    def patch(self, node_id: int) -> PatchRecord:
        try:
            return self.patches[node_id]
        except KeyError:
            raise BusError(f"node {node_id} is not a configured patch") from None

    def report_unknown(self, unknown: UnknownNode) -> None:
        self.unknown_nodes[unknown.node_id] = unknown
        log_unknown(unknown)
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
        self.channels.booted(patch)
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
        # Patches: the heartbeat monitor reports their boot-ups. Force node-IDs: the active
        # policy watches them (a foreign node there is reported; ours echo on udp_multicast).
        if node_id in self.patches or node_id in self.force_ids:
            return
        if node_id in self.config.other_nodes:
            return
        self.policy.on_unknown_boot(link, node_id)


def _step(what: str, step: Callable[[], object]) -> None:
    try:
        step()
    except Exception:
        logger.exception("host stop: %s failed", what)
