"""One bus of the host: its canopen ``Network``, its notifier, its data plane, its SYNC and
its heartbeat consumer.

A link either owns its network (built on the caller's python-can bus, with a notifier of
its own whose one listener is a :class:`~canbus.master.pdo_router.PdoRouter`) or joins a
``canopen.Network`` the caller already runs (an application that is itself a CANopen
master): then the data plane and the SYNC follower are added to that network's notifier
and canopen's own listener keeps seeing every frame, as it did.

A link's own notifier is a :class:`~canbus.receiveloop.ReceiveLoop`: whatever the bus's ``recv``
or a listener raises is counted, logged and survived; a bus that the caller gave as a
:class:`~canbus.busio.ResilientBus` is opened again when it keeps failing, and when it is
gone for good :attr:`BusLink.gone` says why (a joined network keeps its own notifier:
give it a ``ReceiveLoop`` too, :func:`canbus.receiveloop.connect`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable

import can
import canopen

from canbus.busio import ResilientBus
from canbus.master.busconfig import BusConfig
from canbus.master.dataplane import DataPlane
from canbus.master.discovery import BootListener, bound_lss_answers
from canbus.master.liveness import HeartbeatMonitor
from canbus.master.pdo_router import PdoRouter
from canbus.master.sync_producer import SYNC_COB_ID, SyncFollower, SyncProducer
from canbus.receiveloop import ReceiveLoop
from canbus.rxfilter import OwnFrameGate, ReceiveFilter, receive_filter
from skin.errors import BusError

NOTIFIER_CYCLE_S = 0.05  # canopen's notifier recv() timeout: stop() joins within one cycle


class BusLink:
    """The host's view of one bus (``config.name``)."""

    def __init__(self, config: BusConfig, bus: can.BusABC | canopen.Network, *,
                 heartbeat_ms: int, on_boot: Callable[[int], None],
                 on_lost: Callable[[int], None], on_return: Callable[[int, int], None],
                 on_change: Callable[[int, int], None] | None,
                 on_any_boot: Callable[[BusLink, int], None],
                 clock: Callable[[], float] | None = None) -> None:
        self.config = config
        self.name = config.name
        if isinstance(bus, canopen.Network):
            if bus.bus is None:
                raise BusError(f"bus {config.name!r}: the canopen Network is not connected")
            self.network, self.joined = bus, True
            self.bus: can.BusABC = bus.bus
        else:
            self.bus, self.joined = bus, False
            self.network = canopen.Network(bus)
            self.network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
            bound_lss_answers(self.network)
        self.monitor = HeartbeatMonitor(self.network, heartbeat_ms, on_boot=on_boot,
                                        on_lost=on_lost, on_return=on_return,
                                        on_change=on_change,
                                        clock=clock or time.monotonic,
                                        self_checking=clock is None)
        self.boots = BootListener(self.network, lambda node_id: on_any_boot(self, node_id))
        self.dataplane: DataPlane | None = None
        self.sync: SyncProducer | SyncFollower | None = None
        self.gone: str | None = None  # why receiving ended for good on this bus
        self._added: list[can.Listener] = []
        self._gated = False  # our listeners sit behind an OwnFrameGate

    @property
    def fd(self) -> bool:
        """Patches on this bus answer in one CAN FD frame, force nodes publish in one."""
        return self.config.fd

    def listen(self, dataplane: DataPlane | None, follower: SyncFollower | None) -> None:
        """Start receiving: the data plane takes its patches' PDOs, canopen's listener and
        the SYNC follower every other frame, from the first one."""
        self.dataplane = dataplane
        if follower is not None:
            self.sync = follower
        others: list[can.Listener] = [] if self.joined else [*self.network.listeners]
        if follower is not None:
            others.append(follower)
        listeners: list[can.Listener] = [PdoRouter(dataplane, others)] if dataplane is not None \
            else others
        self.boots.start()
        if self.joined:
            notifier = self.network.notifier
            if notifier is None:
                raise BusError(f"bus {self.name!r}: the canopen Network has no notifier")
            for listener in listeners:
                notifier.add_listener(listener)
            self._added = listeners
        else:  # what Network.connect() builds on a given bus, with our listeners first
            self.network.notifier = ReceiveLoop(self.bus, listeners,
                                                timeout=self.network.NOTIFIER_CYCLE,
                                                name=self.name, on_gone=self._on_gone)
        self.monitor.start()

    def _on_gone(self, err: BaseException) -> None:
        self.gone = str(err)

    def receive_report(self) -> dict[str, object]:
        """What receiving from this bus survived (``canbus.busio.ReceiveStats``)."""
        notifier = self.network.notifier
        if isinstance(notifier, ReceiveLoop):
            return dict(notifier.report())
        if isinstance(self.bus, ResilientBus):
            return self.bus.stats.as_dict()
        return {}

    def claim_own(self, cob_ids: Iterable[int]) -> None:
        """The COB-IDs only this host sends on the bus (replacing an earlier claim). Where
        the bus hands a process its own frames back (udp_multicast) their echoes are
        dropped in the kernel (``canbus.rxfilter``), or, where it cannot filter, by a gate
        in front of our listeners; elsewhere nothing changes."""
        own = receive_filter(self.bus)
        if self.dataplane is not None and self.dataplane.sync_echo:
            cob_ids = set(cob_ids) - {SYNC_COB_ID}  # its echo closes the cycle (dataplane)
        own.claim(self, cob_ids)
        if own.echoes and not own.in_kernel and not self._gated:
            self._gate_listeners(own)

    def release_own(self) -> None:
        receive_filter(self.bus).release(self)

    def _gate_listeners(self, own: ReceiveFilter) -> None:
        notifier = self.network.notifier
        if notifier is None:
            return
        gates: list[can.Listener] = []
        for listener in self._added if self.joined else list(notifier.listeners):
            if not isinstance(listener, can.Listener):
                continue
            gate = OwnFrameGate(listener, own)
            if listener in notifier.listeners:
                notifier.listeners[notifier.listeners.index(listener)] = gate
            gates.append(gate)
        if self.joined:
            self._added = gates
        self._gated = True

    def produce_sync(self, period_s: float, counter: bool) -> SyncProducer:
        assert self.dataplane is not None, "listen() first"
        producer = SyncProducer(self.bus, period_s, on_sync=self.dataplane.on_sync_sent,
                                counter=counter)
        self.sync = producer
        return producer

    def stop_sync(self) -> None:
        if isinstance(self.sync, SyncProducer):
            self.sync.stop()

    def close(self) -> None:
        """Stop the heartbeat consumer, boot listener and notifier (it stops the data plane);
        a joined network keeps running, without our listeners."""
        self.monitor.stop()
        self.boots.stop()
        if self.joined:
            notifier = self.network.notifier
            for listener in self._added:
                if notifier is not None and listener in notifier.listeners:
                    notifier.remove_listener(listener)
                listener.stop()
            self._added = []
        elif self.network.notifier is not None:
            self.network.notifier.stop(self.network.NOTIFIER_SHUTDOWN_TIMEOUT)
            self.network.notifier = None
        elif self.dataplane is not None:
            self.dataplane.stop()
