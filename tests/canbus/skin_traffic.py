"""A host's bus as frames, written here frame by frame from a host config, with the truth of
every frame: who sent it, and what each force node published.

What a live host and its patches put on a bus (SYNC with its counter, each patch's answer in
the mapping of its mode, each force node's seven PDOs at its configured COB-IDs, heartbeats,
boot-ups, the host's SDO writes of the patches' mappings, another node's own PDOs), without
the timing of a live run, so that a property test can make hundreds of buses.
"""

from __future__ import annotations

import functools
import struct
from dataclasses import dataclass, field

import can
import numpy as np

from canbus.master.forceframes import forces_to_mN
from canbus.master.forcenode import ForceNode
from canbus.master.hostconfig import HostConfig, PatchConfig
from canbus.master.patch_setup import tpdo_layouts
from canbus.od import load_od
from canbus.pdo_codec import COB_ID_INVALID, TPDO_COMM, TPDO_MAP, PdoCodec

FRAME_S = 50e-6
TPDO_COUNT = 7
OTHER_TPDOS = (0x180, 0x280)


@dataclass(frozen=True)
class Sent:
    """Who sent a PDO frame: node ``node``'s TPDO ``number``."""

    node: int
    number: int


@dataclass(frozen=True)
class Published:
    """One force sample as its force node published it."""

    force_node: int
    patch: int
    timestamp: float  # its last PDO's
    mN: np.ndarray  # (27,) INTEGER16, -32768 = no value
    valid: np.ndarray  # (9,)


@dataclass
class Traffic:
    messages: list[can.Message] = field(default_factory=list)
    senders: list[Sent | None] = field(default_factory=list)  # per message; None: not a PDO
    published: list[Published] = field(default_factory=list)

    def add(self, t: float, cob_id: int, data: bytes, sent: Sent | None = None) -> float:
        self.messages.append(can.Message(timestamp=t, arbitration_id=cob_id, data=data,
                                         is_extended_id=False))
        self.senders.append(sent)
        return t + FRAME_S

    def since(self, start: int) -> Traffic:
        """The same bus recorded from message ``start`` on."""
        t0 = self.messages[start].timestamp if start < len(self.messages) else np.inf
        return Traffic(self.messages[start:], self.senders[start:],
                       [p for p in self.published if p.timestamp >= t0])


@functools.cache
def _force_node(node: int, patch: int) -> ForceNode:
    return ForceNode(node, patch)


@functools.cache
def _patch_codec(node: int, mode: str) -> PdoCodec:
    return PdoCodec(tpdo_layouts(node, mode), load_od("skin-patch", node))


def _sdo(traffic: Traffic, t: float, node: int, index: int, sub: int, value: int,
         size: int) -> float:
    command = 0x23 | ((4 - size) << 2)
    request = struct.pack("<BHB", command, index, sub) + value.to_bytes(size, "little")
    t = traffic.add(t, 0x600 + node, request.ljust(8, b"\0"))
    return traffic.add(t, 0x580 + node, struct.pack("<BHB", 0x60, index, sub) + bytes(4))


def _configure(traffic: Traffic, t: float, patch: PatchConfig) -> float:
    """The host's CiA 301 sequence writing the mapping of the patch's mode."""
    node = patch.node_id
    layouts = {layout.number: layout for layout in tpdo_layouts(node, patch.mode)}
    defaults = [base + node for base in (0x180, 0x280, 0x380, 0x480, 0x200, 0x300, 0x400)]
    for n in range(1, TPDO_COUNT + 1):
        comm, mapping = TPDO_COMM + n - 1, TPDO_MAP + n - 1
        layout = layouts.get(n)
        cob = layout.cob_id if layout is not None else defaults[n - 1]
        t = _sdo(traffic, t, node, comm, 1, cob | COB_ID_INVALID, 4)
        if layout is None:
            continue
        t = _sdo(traffic, t, node, mapping, 0, 0, 1)
        for sub, entry in enumerate(layout.entries, start=1):
            t = _sdo(traffic, t, node, mapping, sub, entry.to_raw(), 4)
        t = _sdo(traffic, t, node, mapping, 0, len(layout.entries), 1)
        t = _sdo(traffic, t, node, comm, 1, cob, 4)
    return t


def traffic(config: HostConfig, *, cycles: int, seed: int, boot: bool = True,
            sdo: bool = True, t0: float = 100.0) -> Traffic:
    """``cycles`` SYNC cycles of ``config``'s bus (classic CAN)."""
    rng = np.random.default_rng(seed)
    out = Traffic()
    period = config.sync_period_ms / 1000.0
    patches = sorted(config.patches, key=lambda p: p.node_id)
    beats = {p.node_id: config.heartbeat_ms for p in patches} | \
        {p.force_node: config.force_heartbeat_ms for p in patches} | \
        dict.fromkeys(config.other_nodes, 100)
    next_beat = {node: t0 + rng.uniform(0, ms / 1000.0) for node, ms in beats.items()}
    t = t0 - 0.05
    if boot:
        for node in sorted(beats):
            t = out.add(t, 0x700 + node, b"\0")
    if sdo:
        for patch in patches:
            t = _configure(out, t, patch)
    for k in range(cycles):
        t = max(t, t0 + k * period)
        t = out.add(t, 0x080, bytes([k % 240 + 1]))
        for patch in patches:
            codec = _patch_codec(patch.node_id, patch.mode)
            codes = rng.integers(18000, 30000, (1, len(codec.variables))).astype(np.float64)
            payloads = codec.pack(codes)[0]
            order = sorted(range(len(codec.layouts)), key=lambda n: codec.layouts[n].cob_id)
            for n in order:
                layout = codec.layouts[n]
                t = out.add(t, layout.cob_id, bytes(payloads[n][:layout.size]),
                            Sent(patch.node_id, layout.number))
        for patch in patches:
            t = _publish(out, t, patch, rng)
        for node in config.other_nodes:
            for number, base in enumerate(OTHER_TPDOS, start=1):
                t = out.add(t, base + node, rng.bytes(8), Sent(node, number))
        for node in sorted(next_beat):
            if next_beat[node] <= t:
                t = out.add(t, 0x700 + node, b"\x05")
                next_beat[node] += beats[node] / 1000.0
    return out


def _publish(out: Traffic, t: float, patch: PatchConfig, rng: np.random.Generator) -> float:
    force = np.round(rng.uniform(-3.0, 6.0, (9, 3)), 3)
    valid = rng.random(9) > 0.1
    frames = _force_node(patch.force_node, patch.node_id).frames(force, valid, True)
    defaults = [cob for cob, _ in frames]  # TPDO 1..8 at the node's predefined COB-IDs
    given = list(patch.force_cob_ids or ())
    cob_ids = [*given, *defaults[len(given):]]  # 7 given: TPDO 8 (the contact) keeps its own
    for n, ((_, data), cob) in enumerate(zip(frames, cob_ids, strict=True), start=1):
        t = out.add(t, cob, data, Sent(patch.force_node, n))
    mN, on_bus = forces_to_mN(force, valid)
    out.published.append(Published(patch.force_node, patch.node_id, t - FRAME_S,
                                   mN.reshape(-1), on_bus))
    return t
