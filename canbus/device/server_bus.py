"""One bus of a :class:`~canbus.device.patch_server.PatchServer`: its nodes, counters, the SYNC
COB-IDs its nodes consume (0x1005, followed as they change), its own frames (claimed where the
bus echoes them) and what a patch is by LSS."""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import canopen

from canbus.device.local_device import eds_identity
from canbus.device.patch_node import PatchNode
from canbus.identity import Identity
from canbus.rxfilter import OwnFrameGate, ReceiveFilter, receive_filter

SYNC_COB_ID = 0x080
SyncCallback = Callable[[int, bytearray, float], None]


@dataclass(eq=False)
class ServerBus:
    """One bus of the server: its network, its nodes in node-ID order, its SYNC count."""

    network: canopen.Network
    nodes: list[PatchNode]
    syncs: int = 0
    frames_sent: int = 0
    last_sync: float = -math.inf
    """``time.monotonic()`` of its last SYNC."""
    answered_at: float = -math.inf
    """``time.monotonic()`` of the end of its last answer."""
    answer_s: deque[float] = field(default_factory=lambda: deque(maxlen=1 << 17))
    """Per answered SYNC: from the SYNC's receive stamp to the return of the last send."""
    late: int = 0
    """Answers that ended after the next SYNC was due (one SYNC interval after theirs):
    more traffic than this process sends in a cycle."""
    last_received: float = 0.0
    """The receive stamp of its last SYNC."""
    send_lock: threading.Lock = field(default_factory=threading.Lock)
    own: ReceiveFilter | None = None
    sync_of: dict[PatchNode, int] = field(default_factory=dict)
    """The SYNC COB-ID each configured node consumes (0x1005)."""
    sync_subscribed: set[int] = field(default_factory=set)
    sync_lock: threading.Lock = field(default_factory=threading.Lock)
    gate: OwnFrameGate | None = None
    on_sync: SyncCallback | None = None


def follow_sync(bus: ServerBus) -> None:
    """Subscribe to the SYNC COB-ID of every configured node of the bus (0x1005)."""
    with bus.sync_lock:
        bus.sync_of = {node: node.sync_cob_id() for node in bus.nodes if node.configured}
        wanted = set(bus.sync_of.values()) or {SYNC_COB_ID}
        assert bus.on_sync is not None
        for cob_id in wanted - bus.sync_subscribed:
            bus.network.subscribe(cob_id, bus.on_sync)
        for cob_id in bus.sync_subscribed - wanted:
            bus.network.unsubscribe(cob_id, bus.on_sync)
        bus.sync_subscribed = wanted


def claim_own_frames(bus: ServerBus, consumed: set[int] | None = None) -> None:
    """Claim the COB-IDs the bus's nodes send, where the bus echoes them, so that its nodes
    never take their own frames for another node's; and accept only ``consumed`` (None:
    everything)."""
    network_bus = bus.network.bus
    if network_bus is None:
        return
    if bus.own is None:
        bus.own = receive_filter(network_bus)
        if consumed is not None:
            bus.own.accept_only(consumed)
    if not bus.own.echoes:
        return
    bus.own.claim(bus, {c for node in bus.nodes for c in node.transmitted_cob_ids()})
    notifier = bus.network.notifier
    if bus.own.in_kernel or notifier is None or bus.gate is not None:
        return
    for k, listener in enumerate(notifier.listeners):
        if isinstance(listener, canopen.network.MessageListener):
            bus.gate = OwnFrameGate(listener, bus.own)
            notifier.listeners[k] = bus.gate


def release_own_frames(bus: ServerBus, *, accepted_only: bool = False) -> None:
    """Undo :func:`claim_own_frames` (``accepted_only``: it was given ``consumed``): the
    bus's receive filter and gate as they were."""
    if bus.own is None:
        return
    bus.own.release(bus)
    if accepted_only:
        bus.own.accept_only(None)
    notifier = bus.network.notifier
    if bus.gate is not None and notifier is not None:
        listeners = notifier.listeners
        if bus.gate in listeners:
            listeners[listeners.index(bus.gate)] = bus.gate.listener
    bus.gate = None
    bus.own = None


def answer_order(node: PatchNode) -> int:
    return node.node_id


def patch_identity(serial: int) -> Identity:
    """The LSS address of a patch with ``serial`` (vendor, product, revision of its EDS)."""
    return Identity(*eds_identity("skin-patch"), serial=serial)
