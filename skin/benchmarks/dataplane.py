# canopen 2.4 ships py.typed but leaves many methods unannotated.
# mypy: disable-error-code="no-untyped-call"
"""Benchmark: the data plane against the same work through canopen's PdoMap callbacks.

Both paths take the same stream of patch TPDO frames (``can.Message`` objects built once
from simulator resistances encoded by the patches' own ``PdoCodec``, in CAN arbitration
order, stamped inside each SYNC cycle's window), decode them with one shared ``analytic``
decoder and send the same force TPDOs to a sink bus, one after the other in one thread:

* data plane: :class:`canbus.master.dataplane.DataPlane` (``background=False``), frames given
  to ``on_message_received``, then ``publish_pending()`` once per cycle (every patch
  completed in the cycle decoded in one batch, as the publishing thread batches them
  when the bus is busy); force nodes are :class:`canbus.master.forcenode.ForceNode`.
* canopen: a ``RemoteNode`` per patch whose TPDO maps hold the patch's mapping; frames
  go through canopen's own ``MessageListener`` (``network.notify`` -> ``PdoMap.on_message``
  -> one callback per map reading ``var.raw``); per cycle the codes are turned into
  resistances and decoded in one batch (the same batching, so the comparison is the
  frame handling), then each force node, a canopen ``LocalNode`` with
  eds/skin-forces.eds, sets its TPDO variables (``var.raw = ...``) and ``transmit()``.

What the figures exclude: python-can's delivery of frames from the bus to a listener
(a virtual bus deep-copies each frame into a queue that the ``Notifier`` thread reads);
:func:`notifier_rate` measures that part alone.
"""

from __future__ import annotations

import threading
import time
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
from decoder.registry import create_decoder
from skin.errors import BusError, ConfigError

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


def _timed(run: Any) -> tuple[float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    run()
    return time.perf_counter() - wall, time.process_time() - cpu


class QueuedFrames:
    """``frames`` frames waiting on a virtual bus for a python-can ``Notifier`` to deliver."""

    def __init__(self, frames: int) -> None:
        self.frames = frames
        channel = f"dataplane-bench-{id(self)}"
        self.sender = can.Bus(interface="virtual", channel=channel)
        self.receiver = can.Bus(interface="virtual", channel=channel)
        self.notifier: can.Notifier | None = None
        msg = can.Message(arbitration_id=0x181, data=bytes(8), is_extended_id=False)
        for _ in range(frames):
            self.sender.send(msg)

    def deliver(self) -> float:
        """Seconds for a ``Notifier`` to hand every queued frame to a listener."""
        done = threading.Event()
        count = 0

        def on_message(msg: can.Message) -> None:
            nonlocal count
            count += 1
            if count == self.frames:
                done.set()

        start = time.perf_counter()
        self.notifier = can.Notifier(self.receiver, [on_message], timeout=0.05)
        finished = done.wait(60.0)
        elapsed = time.perf_counter() - start
        if not finished:
            raise BusError(f"the notifier delivered {count} of {self.frames} frames")
        return elapsed

    def close(self) -> None:
        """Stop the notifier (it may wait out its ``recv`` time-out) and the buses."""
        if self.notifier is not None:
            self.notifier.stop(timeout=1.0)
        self.sender.shutdown()
        self.receiver.shutdown()


def notifier_rate(frames: int = 20_000) -> float:
    """Frames/s a ``Notifier`` takes from a virtual bus to a listener (``bus.recv`` and
    dispatch; the frames are queued beforehand, so the sender's share is not counted)."""
    queued = QueuedFrames(frames)
    try:
        return frames / queued.deliver()
    finally:
        queued.close()


def notifier_threads(bus: can.BusABC) -> list[str]:
    """The name python-can gives the receive thread of a ``Notifier`` on ``bus``."""
    return [f'Notifier for bus "{bus.channel_info}"']


class ReceiveSideClock:
    """The CPU time the named threads (the receive side: the Notifier's thread, the data
    plane's) spend from now on, read from each thread's own CPU clock: the sender in the
    same process, and the GIL it holds, are not counted."""

    def __init__(self, names: list[str]) -> None:
        threads = {t.name: t for t in threading.enumerate()}
        missing = [name for name in names if name not in threads]
        if missing:
            raise BusError(f"no thread named {missing} to time")
        self.clocks = [time.pthread_getcpuclockid(threads[n].ident or 0) for n in names]
        self.start = [time.clock_gettime(c) for c in self.clocks]

    def seconds(self) -> float:
        return sum(time.clock_gettime(c) - s for c, s in zip(self.clocks, self.start,
                                                               strict=True))


def pipeline_rate(stream: Stream, decoder: Decoder,
                  contact: Callable[[int], PatchContact] | None = None, *,
                  bus: dict[str, Any] | None = None, recorder: Any = None,
                  pace: float | None = None) -> dict[str, float]:
    """The whole path in one process: a bus -> ``Notifier`` -> data plane (its thread).

    The sender opens each cycle (``on_sync``), sends its frames and waits until the data
    plane has taken them all before the next SYNC, as a SYNC-paced bus would. ``bus``:
    python-can's arguments of the bus (default: a virtual channel of its own).
    ``recorder``: a recorder beside it, as ``skin run --record`` runs one, given every
    sample the publisher hands out (``on_forces``); a ``can.Listener`` (an in-process
    :class:`~canbus.tools.recorder.Recorder`) also gets the frames from a bus of its own.
    ``pace``: frames/s at most, each cycle sent at its time (a bus's rate, not the most).
    """
    bus = bus or {"interface": "virtual", "channel": f"dataplane-pipeline-{id(stream)}"}
    from canbus.rxbuffer import DEFAULT_RCVBUF, enlarge_receive_buffer

    sender = can.Bus(**bus)
    receiver = can.Bus(**bus)
    enlarge_receive_buffer(receiver, DEFAULT_RCVBUF)  # as the commands do (a socket bus)
    rig = DataPlaneRig(stream, decoder, background=True, window_s=0.0, contact=contact)
    notifier = can.Notifier(receiver, [rig.plane], timeout=0.05)
    receiving = ReceiveSideClock([*notifier_threads(receiver), "dataplane"])
    tap = None
    if isinstance(recorder, can.Listener):
        tapped = can.Bus(**bus)
        enlarge_receive_buffer(tapped, DEFAULT_RCVBUF)
        tap = can.Notifier(tapped, [recorder], timeout=0.05)
    if recorder is not None:

        def record(batch: list[ForceFrame]) -> None:
            for frame in batch:
                recorder.on_forces(frame)

        rig.plane.subscribe(record)
    per_cycle = len(stream.frames[0])
    try:
        start = time.perf_counter()
        for k, frames in enumerate(stream.frames):
            if pace is not None:
                due = start + k * per_cycle / pace
                time.sleep(max(0.0, due - time.perf_counter()))
            rig.plane.on_sync(k + 1, 0, time.time())
            for msg in frames:
                sender.send(msg)
            deadline = time.monotonic() + 10.0
            while rig.plane.stats.frames_in < (k + 1) * per_cycle:
                if time.monotonic() > deadline:
                    raise BusError(f"the data plane took {rig.plane.stats.frames_in} of "
                                   f"{(k + 1) * per_cycle} frames")
                time.sleep(50e-6)
        rig.plane.flush()
        elapsed = time.perf_counter() - start
        receive_cpu = receiving.seconds()
        stats = rig.plane.stats.snapshot()
    finally:
        notifier.stop(timeout=1.0)
        if tap is not None:
            tap.stop(timeout=1.0)  # and the recorder: written out and closed
            tap.bus.shutdown()  # type: ignore[union-attr]
        sender.shutdown()
        receiver.shutdown()
        rig.close()
    return {"frames_per_s": stats["frames_in"] / elapsed,
            "receive_frames_per_cpu_s": stats["frames_in"] / max(receive_cpu, 1e-9),
            "complete": float(stats["complete_samples"] == stats["samples"]),
            "mean_batch": stats["samples"] / max(stats["batches"], 1)}


def contact_judge(node_id: int) -> PatchContact:
    """A patch's contact judge as a host config without ``[contact]`` gives it."""
    return PatchContact()


def run_dataplane_benchmark(patches: int = 16, cycles: int = 300, mode: str = "xyz", *,
                            repeats: int = 3, seed: int = 0,
                            contact: bool = True) -> dict[str, Any]:
    """Figures of both paths over the same stream; the best of ``repeats`` interleaved runs.

    Also python-can's delivery alone (:func:`notifier_rate`) and the whole threaded path
    (:func:`pipeline_rate`), each the best of its runs. ``contact``: the force nodes publish
    their patches' contact summaries (TPDO 8), as a host does by default.
    """
    stream = build_stream(patches, cycles, mode, seed)
    decoder = create_decoder("analytic")
    judge = contact_judge if contact else None
    fast = DataPlaneRig(stream, decoder, contact=judge)
    slow = CanopenRig(stream, decoder, contact=judge)
    try:
        fast.run(stream)
        slow.run(stream)
        identical = fast.sink.sent == slow.sink.sent
        frames_out = len(fast.sink.sent)
        times: dict[str, list[tuple[float, float]]] = {"dataplane": [], "per_patch": [],
                                                       "canopen": []}
        for _ in range(repeats):
            times["dataplane"].append(_timed(lambda: fast.run(stream)))
            times["per_patch"].append(_timed(lambda: fast.run(stream, per_patch=True)))
            times["canopen"].append(_timed(lambda: slow.run(stream)))
        stats = fast.plane.stats.snapshot()
    finally:
        fast.close()
        slow.close()
    n = stream.frame_count
    best = {k: min(v) for k, v in times.items()}
    result: dict[str, Any] = {
        "patches": patches, "cycles": cycles, "mode": mode, "repeats": repeats,
        "contact": contact,
        "frames_in": n, "frames_out": frames_out, "identical_output": identical,
        "all_samples_complete": stats["incomplete_samples"] == 0,
    }
    for key, (wall, cpu) in best.items():
        result[f"{key}_s"] = wall
        result[f"{key}_cpu_share"] = cpu / wall
        result[f"{key}_frames_in_per_s"] = n / wall
        result[f"{key}_frames_out_per_s"] = frames_out / wall
    result["speedup"] = best["canopen"][0] / best["dataplane"][0]
    result["speedup_per_patch"] = best["canopen"][0] / best["per_patch"][0]
    result["notifier_frames_per_s"] = max(notifier_rate() for _ in range(repeats))
    pipeline = max((pipeline_rate(stream, decoder, judge) for _ in range(min(repeats, 3))),
                   key=lambda figures: figures["frames_per_s"])
    result["pipeline_frames_per_s"] = pipeline["frames_per_s"]
    result["pipeline_receive_frames_per_cpu_s"] = pipeline["receive_frames_per_cpu_s"]
    own_cpu_s = best["dataplane"][1]  # the data plane's own path, on the same kind of clock
    result["pipeline_receive_vs_dataplane"] = pipeline["receive_frames_per_cpu_s"] * own_cpu_s / n
    result["pipeline_mean_batch"] = pipeline["mean_batch"]
    result["pipeline_all_complete"] = bool(pipeline["complete"])
    return result
