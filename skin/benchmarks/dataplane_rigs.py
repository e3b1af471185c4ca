# canopen 2.4 ships py.typed but leaves many methods unannotated.
# mypy: disable-error-code="no-untyped-call"
"""The data plane's benchmark rigs: a stream of patch TPDO frames built from the simulator
(:func:`build_stream`), the data plane with its force nodes publishing to a sink
(:class:`DataPlaneRig`) and the same work through canopen's PdoMap callbacks
(:class:`CanopenRig`). :mod:`skin.benchmarks.dataplane` times them against each other,
:mod:`skin.benchmarks.pipeline` the data plane behind a bus and a ``Notifier``."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import can
import canopen
import numpy as np
from numpy.typing import NDArray

from canbus import codes, contact_record
from canbus.device.patch_node import PatchNode
from canbus.master.contact import ContactSummarizer, PatchContact
from canbus.master.dataplane import DataPlane, ForceFrame, PatchChannel
from canbus.master.forceframes import VALID, forces_to_mN, valid_bits
from canbus.master.forcenode import ForceNode
from canbus.od import load_od
from decoder.protocol import Decoder
from skin.errors import ConfigError

PERIOD_S = 0.01
FORCE_NODE_OFFSET = 64
SCENES = {"xyz": "indenter", "z": "paper"}


class SinkBus(can.BusABC):
    """A bus that keeps what is sent to it and never receives."""

    def __init__(self) -> None:
        super().__init__(channel="sink")
        self.sent: list[tuple[int, bytes]] = []

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sent.append((msg.arbitration_id, bytes(msg.data)))

    def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:
        return None, False


@dataclass(frozen=True)
class Stream:
    """Patch TPDO frames of ``cycles`` SYNC cycles and the patch nodes that produced them."""

    nodes: list[PatchNode]
    sync_times: list[float]
    frames: list[list[can.Message]]  # per cycle, in arbitration order

    @property
    def frame_count(self) -> int:
        return sum(len(cycle) for cycle in self.frames)


def build_stream(patches: int, cycles: int, mode: str, seed: int = 0) -> Stream:
    """``cycles`` SYNC cycles of ``patches`` simulated patches, as patch TPDO frames."""
    import sim

    if mode not in SCENES:
        raise ConfigError("mode", f"must be 'xyz' or 'z', got {mode!r}")
    if not 1 <= patches <= 63:
        raise ConfigError("patches", f"must be in 1..63 (force nodes at +64), got {patches}")
    dataset = sim.generate_dataset(SCENES[mode], cycles * patches, seed)
    return stream_of(dataset.resistance_ohm.reshape(cycles, patches, 9, -1), mode)


def stream_of(resistance_ohm: NDArray[np.float64], mode: str) -> Stream:
    """The patch TPDO frames of ``(cycles, patches, 9, P)`` resistances: patch p is node
    p + 1, cycle k one SYNC, each patch's TPDOs packed by its own ``PdoCodec``."""
    r = resistance_ohm
    cycles, patches = r.shape[:2]
    nodes = [PatchNode(p + 1, mode=mode) for p in range(patches)]
    per_patch = []
    for p, node in enumerate(nodes):
        codec = node.tpdo.codec
        c = codes.resistance_to_code(r[:, p], node.constants.resistance_lsb_ohm)
        full = np.full((cycles, 9, 3), codes.OPEN, dtype=np.uint16)
        full[..., : c.shape[-1]] = c
        flat = full.reshape(cycles, 27)
        values = np.stack([flat[:, s - 1] for _, s in codec.variables], axis=1)
        payloads = codec.pack(values)
        per_patch.append([(int(cob), payloads[:, n, :size])
                          for n, (cob, size) in enumerate(zip(codec.cob_ids, codec.sizes,
                                                              strict=True))])
    sync_times = [1e6 + k * PERIOD_S for k in range(cycles)]  # any clock: windows are relative
    frames = []
    for k, t0 in enumerate(sync_times):
        cycle = sorted((cob, bytes(data[k])) for pdos in per_patch for cob, data in pdos)
        spacing = 0.5 * PERIOD_S / len(cycle)  # all inside the window (0.9 period)
        frames.append([can.Message(timestamp=t0 + (j + 1) * spacing, arbitration_id=cob,
                                   data=data, is_extended_id=False)
                       for j, (cob, data) in enumerate(cycle)])
    return Stream(nodes, sync_times, frames)


class DataPlaneRig:
    """The data plane with its force nodes, publishing to a sink; ``contact``: the force
    nodes' contact judges (:func:`contact_judge`), None: no contact summary."""

    def __init__(self, stream: Stream, decoder: Decoder, *, background: bool = False,
                 window_s: float = 0.9 * PERIOD_S,
                 contact: Callable[[int], PatchContact] | None = None) -> None:
        self.sink = SinkBus()
        self.network = canopen.Network(self.sink)
        self.force_nodes = []
        self.plane = DataPlane(self.sink, sync_window_s=window_s, background=background)
        for node in stream.nodes:
            force_node = ForceNode(node.node_id + FORCE_NODE_OFFSET, node.node_id, heartbeat_ms=0,
                                   contact=None if contact is None else contact(node.node_id))
            force_node.attach(self.network)
            force_node.start()
            self.force_nodes.append(force_node)
            self.plane.add_channel(PatchChannel(
                node.node_id, node.tpdo.codec, node.pillars, node.constants.resistance_lsb_ohm,
                decoder, force_node))
        self.sink.sent.clear()  # boot-up messages

    def run(self, stream: Stream, *, per_patch: bool = False) -> None:
        """Every cycle of ``stream``; ``per_patch`` publishes after each frame (batches of 1)."""
        plane, receive = self.plane, self.plane.on_message_received
        for k, (t0, frames) in enumerate(zip(stream.sync_times, stream.frames, strict=True)):
            plane.on_sync(k + 1, 0, t0)
            if per_patch:
                for msg in frames:
                    receive(msg)
                    plane.publish_pending()
            else:
                for msg in frames:
                    receive(msg)
                plane.publish_pending()
        plane.flush()

    def close(self) -> None:
        self.plane.stop()
        for node in self.force_nodes:
            node.detach()
        self.sink.shutdown()


def published_frames(stream: Stream, decoder: Decoder,
                     contact: Callable[[int], PatchContact] | None = None) -> list[ForceFrame]:
    """Every force frame the data plane publishes for ``stream``, in publishing order."""
    rig = DataPlaneRig(stream, decoder, contact=contact)
    frames: list[ForceFrame] = []
    rig.plane.subscribe(frames.extend)
    try:
        rig.run(stream)
    finally:
        rig.close()
    return frames


class CanopenRig:
    """The same work the canopen way: PdoMap callbacks in, PdoMap transmit out; with
    ``contact``, each force node's contact PDO too (the same summaries)."""

    def __init__(self, stream: Stream, decoder: Decoder, *,
                 contact: Callable[[int], PatchContact] | None = None) -> None:
        self.decoder = decoder
        self.contacts = None if contact is None else [contact(n.node_id) for n in stream.nodes]
        self.summarizer = ContactSummarizer()
        self.sink = SinkBus()
        self.network = canopen.Network(self.sink)
        self.listener = canopen.network.MessageListener(self.network)
        first = stream.nodes[0]
        self.pillars = first.pillars
        self.lsb = np.array([n.constants.resistance_lsb_ohm for n in stream.nodes])[:, None, None]
        self.codes = np.zeros((len(stream.nodes), 9, self.pillars), dtype=np.uint16)
        self.received = [0] * len(stream.nodes)
        self.full: list[int] = []
        self.carried: list[list[NDArray[np.bool_]]] = []
        for p, node in enumerate(stream.nodes):
            remote = self.network.add_node(canopen.RemoteNode(node.node_id,
                                                              _configured_od(node)))
            remote.tpdo.read(from_od=True)  # the node's mapping, as a master reads it
            maps = [m for m in remote.tpdo.values() if m.enabled]
            self.full.append((1 << len(maps)) - 1)
            self.carried.append([])
            for bit, pdo in enumerate(maps):
                self.carried[p].append(self._watch(pdo, p, 1 << bit))
        self.publishers = []
        for node in stream.nodes:
            fid = node.node_id + FORCE_NODE_OFFSET
            local = canopen.LocalNode(fid, load_od("skin-forces", fid))
            self.network.add_node(local)
            local.tpdo.read(from_od=True)
            self.publishers.append([(pdo, [_force_column(v.index, v.subindex) for v in pdo])
                                    for pdo in local.tpdo.values() if pdo.enabled and (
                                        self.contacts is not None or not _maps_contact(pdo))])
        self.sink.sent.clear()

    def _watch(self, pdo: Any, patch: int, bit: int) -> NDArray[np.bool_]:
        """Subscribe one callback to ``pdo``; the taxels it carries."""
        flat = self.codes.reshape(len(self.received), -1)
        cols = [((v.subindex - 1) // 3) * self.pillars + (v.subindex - 1) % 3 for v in pdo
                if v.index == 0x2000 and (v.subindex - 1) % 3 < self.pillars]

        def on_map(pdo_map: Any) -> None:
            flat[patch, cols] = [v.raw for v in pdo_map]
            self.received[patch] |= bit

        pdo.add_callback(on_map)
        carried = np.zeros(9, dtype=bool)
        carried[[c // self.pillars for c in cols]] = True
        return carried

    def run(self, stream: Stream) -> None:
        receive = self.listener.on_message_received
        for frames in stream.frames:
            for msg in frames:
                receive(msg)
            self._publish()

    def _publish(self) -> None:
        complete = np.array([r == f for r, f in zip(self.received, self.full, strict=True)])
        r = codes.code_to_resistance(self.codes, 1.0) * self.lsb
        missing = np.zeros((len(self.received), 9), dtype=bool)
        for p in np.flatnonzero(~complete):
            for bit, carried in enumerate(self.carried[p]):
                if not self.received[p] >> bit & 1:
                    missing[p] |= carried
        r[missing] = np.nan
        decoded = self.decoder.decode(r)
        valid = decoded.valid & ~missing
        mN, bus_valid = forces_to_mN(decoded.force_N, valid)
        bits = valid_bits(bus_valid, complete)
        parts: list[NDArray[np.int64]] = [mN.reshape(len(mN), 27).astype(np.int64),
                                          bits[:, None].astype(np.int64)]
        if self.contacts is not None:
            force = np.where(valid[..., None], decoded.force_N, 0.0)
            batch = self.summarizer.batch(self.contacts, force, valid)
            parts.append(contact_record.encode(batch, range(1, contact_record.SUBS + 1)))
        rows: list[list[int]] = np.concatenate(parts, axis=1).tolist()
        for row, maps in zip(rows, self.publishers, strict=True):
            for pdo, columns in maps:
                for var, column in zip(pdo, columns, strict=True):
                    var.raw = row[column]
                pdo.transmit()
        self.received = [0] * len(self.received)

    def close(self) -> None:
        self.sink.shutdown()


def _configured_od(node: PatchNode) -> canopen.ObjectDictionary:
    """The patch's object dictionary with its current PDO parameters as values (like a DCF)."""
    od = load_od("skin-patch", node.node_id)
    for n in range(7):
        for index, subs in ((0x1800 + n, (1, 2)), (0x1A00 + n, range(9))):
            record = od[index]
            assert isinstance(record, canopen.objectdictionary.ODRecord)
            for s in subs:
                record[s].value = int(node.store.value(index, s))
    return od


def _maps_contact(pdo: Any) -> bool:
    return any(v.index == contact_record.CONTACT for v in pdo)


def _force_column(index: int, subindex: int) -> int:
    if index == VALID:
        return 27
    if index == contact_record.CONTACT:
        return 27 + subindex
    if index != 0x2000:
        raise ConfigError("pdo mapping", f"0x{index:04X} is not published by the benchmark")
    return subindex - 1


def contact_judge(node_id: int) -> PatchContact:
    """A patch's contact judge as a host config without ``[contact]`` gives it."""
    return PatchContact()
