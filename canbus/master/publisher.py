"""The data plane's second half, publishing: queued samples decoded in numpy batches (one
unpack per PDO layout, one ``decode`` per decoder object), the force nodes' TPDOs sent
with ``bus.send``, the API's frames handed to the subscribers, each patch's last complete
sample kept (raw and decoded) for tare and drift tracking, and the warm-up that runs
this same path once before the first cycle.

Subscribers (:meth:`Publisher.subscribe`) are how anything else hooks into the forces:
``callback(frames)`` gets each published batch, a list of
:class:`~canbus.master.channel.ForceFrame` in the order they were published, on the
publishing thread, after the batch's force TPDOs went onto the bus. Keep it short (the
next batch waits for it) and do not block: a slow consumer should queue and drop, as
``canbus.master.fanout`` does. An exception is logged and counted
(``callback_errors``); the other subscribers still get the batch.

Raw subscribers (:meth:`Publisher.subscribe_raw`) get each batch as it was before the
host's scale and decoders: ``callback(samples)``, a list of
:class:`~canbus.master.rawsample.RawSample` (the resistances as the patches sent them),
one per sample of the batch (a sample whose decoder failed too), in the order they were
published; on the publishing thread, after the force frames went to the subscribers,
under the same rules.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Sequence

import can
import numpy as np
from numpy.typing import NDArray

from canbus.codes import code_to_resistance
from canbus.master.channel import (
    DataPlaneStats,
    ForceFrame,
    PatchChannel,
    SampleJob,
    Subscriber,
)
from canbus.master.contact import ContactSummarizer, contact_rows
from canbus.master.forceframes import FrameBatcher
from canbus.master.forcenode import ForceNode
from canbus.master.rawsample import RawSample, RawSubscriber, raw_samples
from canbus.txmessage import TxMessage
from decoder.protocol import Decoder
from decoder.reasons import Reason
from skin.constants import TAXELS_PER_PATCH

logger = logging.getLogger(__name__)


class Publisher:
    """Publishes batches of :class:`SampleJob` (one caller at a time: the data plane's
    publishing lock); keeps each patch's last complete sample, raw and decoded."""

    def __init__(self, bus: can.BusABC, stats: DataPlaneStats) -> None:
        self.bus = bus
        self.stats = stats
        self._subscribers: tuple[Subscriber, ...] = ()  # replaced, never mutated
        self._raw_subscribers: tuple[RawSubscriber, ...] = ()  # likewise
        self._subscribing = threading.Lock()
        self._summarizer = ContactSummarizer()
        self._batcher = FrameBatcher()
        self._raw: dict[int, NDArray[np.float64]] = {}
        self.steady_from_cycle: int | None = None
        """Samples of this cycle on are the steady state's (set by the data plane)."""
        self._last_complete: dict[int, ForceFrame] = {}

    # -- subscribers, tare state --------------------------------------------------------

    def subscribe(self, callback: Subscriber) -> None:
        """Call ``callback(frames)`` with every published batch (module docstring)."""
        with self._subscribing:
            self._subscribers = (*self._subscribers, callback)

    def unsubscribe(self, callback: Subscriber) -> None:
        with self._subscribing:
            self._subscribers = tuple(c for c in self._subscribers if c != callback)

    def subscribe_raw(self, callback: RawSubscriber) -> None:
        """Call ``callback(samples)`` with every published batch's raw samples (module
        docstring)."""
        with self._subscribing:
            self._raw_subscribers = (*self._raw_subscribers, callback)

    def unsubscribe_raw(self, callback: RawSubscriber) -> None:
        with self._subscribing:
            self._raw_subscribers = tuple(c for c in self._raw_subscribers if c != callback)

    def raw_sample(self, node_id: int) -> NDArray[np.float64] | None:
        """The last complete ``(9, P)`` resistances of a patch in ohm, before its scale."""
        sample = self._raw.get(node_id)
        return None if sample is None else sample.copy()

    def tare(self, channel: PatchChannel) -> None:
        """Re-zero the channel's baseline at the patch's last complete sample (raises
        ``PatchLoadedError`` while it is loaded or before its first complete sample)."""
        baseline = channel.baseline
        assert baseline is not None, "the data plane checks it"
        last = self._last_complete.get(channel.node_id)
        baseline.tare(self.raw_sample(channel.node_id), None if last is None else last.force_N,
                      None if last is None else last.valid, node_id=channel.node_id)

    # -- publishing ---------------------------------------------------------------------

    def publish(self, jobs: list[SampleJob]) -> None:
        """Decode the jobs, send their force TPDOs, hand the frames to the subscribers and
        the raw samples to the raw subscribers."""
        force, valid, reason, decoded, samples = self._decode(jobs, errors=True)
        if decoded.all():
            self._send(jobs, force, valid, reason)
        else:
            kept = np.flatnonzero(decoded)
            self._send([jobs[i] for i in kept], force[kept], valid[kept], reason[kept])
        if samples:
            self._hand_raw(samples)

    def warm_up(self, jobs: list[SampleJob]) -> None:
        """Run the publishing path once on these samples (at rest), sending nothing and
        keeping nothing, so that the first cycle does not pay for code and tables run the
        first time; a decoder that fails here raises."""
        if not jobs:
            return
        force, valid, reason, _, _ = self._decode(jobs, errors=False)
        nodes = [job.slot.channel.force_node for job in jobs]
        self._batcher.frames(nodes, force, valid, np.zeros(len(jobs), bool), reason, 0)
        for node in nodes:
            node.clear_sample()  # an SDO read shows "no value" until the first sample

    def _decode(self, jobs: list[SampleJob], *, errors: bool) -> tuple[
            NDArray[np.float64], NDArray[np.bool_], NDArray[np.uint8], NDArray[np.bool_],
            list[RawSample]]:
        """Forces, validity, reasons, which rows decoded and, for the raw subscribers, the
        raw samples; ``errors``: a failing decoder is logged and counted (else it raises;
        a warm-up, which hands nothing on)."""
        n = len(jobs)
        missing = np.zeros((n, TAXELS_PER_PATCH), dtype=bool)
        masked = np.zeros((n, TAXELS_PER_PATCH), dtype=bool)
        for i, job in enumerate(jobs):
            if job.missing:
                missing[i] = job.slot.taxels_of(job.missing)
            masked[i] = job.slot.channel.masked
        raw: dict[int, NDArray[np.float64]] | None = \
            {} if errors and self._raw_subscribers else None
        resistance = self._resistances(jobs, missing | masked, keep=errors, raw_out=raw)
        samples = [] if raw is None else raw_samples(jobs, raw, missing, masked)
        force = np.zeros((n, TAXELS_PER_PATCH, 3))
        reason = np.zeros((n, TAXELS_PER_PATCH), dtype=np.uint8)
        decoded = np.zeros(n, dtype=bool)
        for rows, decoder in by_decoder(jobs):
            try:
                pillars = jobs[rows[0]].slot.channel.pillars
                result = decoder.decode(resistance[rows, :, :pillars])
            except Exception:
                if not errors:
                    raise
                logger.exception("data plane: %r failed on patches %s", decoder,
                                 [jobs[i].slot.channel.node_id for i in rows])
                self.stats.decode_errors += len(rows)
                continue
            force[rows] = result.force_N
            reason[rows] = result.reason
            decoded[rows] = True
        reason[missing] = Reason.MISSING
        reason[masked] = Reason.FAULTY
        valid = reason == 0
        force[~valid] = 0.0
        return force, valid, reason, decoded, samples

    def _resistances(self, jobs: Sequence[SampleJob], undecodable: NDArray[np.bool_], *,
                     keep: bool, raw_out: dict[int, NDArray[np.float64]] | None = None
                     ) -> NDArray[np.float64]:
        """``(n, 9, 3)``: each job's ``(9, P)`` ohms in ``[:, :, :P]``, scaled, NaN where
        ``undecodable``; one unpack per layout. ``raw_out``: gets job i's ohms before the
        scale as ``raw_out[i]``.

        NaN, not a stale or faulty reading, so that a decoder that couples taxels (deconv)
        treats those taxels as invalid rather than spreading them to their neighbours.
        """
        out = np.full((len(jobs), TAXELS_PER_PATCH, 3), np.nan)
        groups: dict[int, list[int]] = {}
        for i, job in enumerate(jobs):
            groups.setdefault(job.slot.key, []).append(i)
        for rows in groups.values():
            first = jobs[rows[0]].slot
            blob = b"".join(jobs[i].payload for i in rows)
            if first.words is not None:
                codes = np.frombuffer(blob, dtype="<u2").reshape(len(rows), -1)[:, first.words]
            else:
                codec = first.channel.codec
                payload = np.frombuffer(blob, dtype=np.uint8).reshape(
                    len(rows), len(codec.layouts), first.stride)[:, :, :codec.width]
                codes = codec.unpack(payload)[:, first.columns]
            channels = [jobs[i].slot.channel for i in rows]
            lsb = {channel.lsb_ohm for channel in channels}
            if len(lsb) == 1:  # open/saturated: +inf
                raw = code_to_resistance(codes, lsb.pop())
            else:
                raw = code_to_resistance(codes, 1.0) * np.array(
                    [channel.lsb_ohm for channel in channels])[:, None, None]
            for m, i in enumerate(rows):
                if keep and jobs[i].complete:
                    self._raw[channels[m].node_id] = raw[m]
            if raw_out is not None:
                raw_out.update(zip(rows, raw, strict=True))
            shape = raw.shape[1:]
            scales = [channel.scale if channel.baseline is None else channel.baseline.scale
                      for channel in channels]
            if all(np.shape(scale_) == shape for scale_ in scales):
                scale = np.array(scales, dtype=np.float64)
            else:
                scale = np.empty_like(raw)
                for m, scale_ in enumerate(scales):
                    scale[m] = scale_  # broadcast to (9, P)
            scaled = raw * scale
            scaled[undecodable[rows]] = np.nan
            out[rows, :, : first.channel.pillars] = scaled
        return out

    def _send(self, jobs: list[SampleJob], force: NDArray[np.float64], valid: NDArray[np.bool_],
              reason: NDArray[np.uint8]) -> None:
        if not jobs:
            return
        complete = [job.complete for job in jobs]
        nodes = [job.slot.channel.force_node for job in jobs]
        contact = self._summarizer.nodes(nodes, force, valid)
        frames = self._batcher.frames(nodes, force, valid, np.array(complete), reason,
                                      [job.cycle[1] for job in jobs], contact)
        # Every frame onto the bus first: the frames for the API come after.
        published = [node.transmitting and self._transmit(f, bus_of(node, self.bus))
                     for node, f in zip(nodes, frames, strict=True)]
        out = []
        summaries = contact_rows(contact, nodes)
        for i, job in enumerate(jobs):
            cycle, counter, timestamp = job.cycle
            judge = nodes[i].contact
            placed = judge is not None and judge.placement is not None
            out.append(ForceFrame(job.slot.channel.node_id, nodes[i].node_id, cycle, counter,
                                  timestamp, force[i], valid[i], reason[i], job.complete,
                                  published[i], summaries[i],
                                  *((judge.placement, judge.geometry.pitch_m)
                                    if placed and judge is not None else ())))
        self._follow_baselines(jobs, out)
        stats = self.stats
        stats.samples += len(out)
        stats.batches += 1
        stats.complete_samples += sum(complete)
        stats.incomplete_samples += len(out) - sum(complete)
        steady_from = self.steady_from_cycle
        if steady_from is not None:
            steady = [f.complete for f in out if f.cycle >= steady_from]
            stats.steady_samples += len(steady)
            stats.steady_complete_samples += sum(steady)
        for callback in self._subscribers:
            try:
                callback(out)
            except Exception:
                stats.callback_errors += 1
                logger.exception("data plane: subscriber %r failed", callback)

    def _hand_raw(self, samples: list[RawSample]) -> None:
        for callback in self._raw_subscribers:
            try:
                callback(samples)
            except Exception:
                self.stats.callback_errors += 1
                logger.exception("data plane: raw subscriber %r failed", callback)

    def _follow_baselines(self, jobs: list[SampleJob], frames: list[ForceFrame]) -> None:
        """Remember each patch's last complete sample (for tare) and track drift on it."""
        for job, out in zip(jobs, frames, strict=True):
            if not out.complete:
                continue
            previous = self._last_complete.get(out.patch)
            self._last_complete[out.patch] = out
            baseline = job.slot.channel.baseline
            raw = self._raw.get(out.patch)
            if baseline is None or baseline.time_constant_s is None or raw is None:
                continue
            dt = out.timestamp - previous.timestamp if previous is not None else 0.0
            baseline.track(raw, out.force_N, out.valid, max(dt, 0.0))

    def _transmit(self, frames: list[tuple[int, bytes]], bus: can.BusABC) -> bool:
        send, frame, sent = bus.send, TxMessage.frame, 0
        try:
            for cob, payload in frames:
                send(frame(cob, payload))
                sent += 1
        except can.CanError as err:
            self.stats.send_errors += 1
            logger.warning("data plane: force TPDO not sent: %s", err)
            return False
        finally:
            self.stats.frames_out += sent
        return True


def bus_of(node: ForceNode, default: can.BusABC) -> can.BusABC:
    """The bus a force node publishes on: the one it is attached to (several buses)."""
    network = node.network
    bus = network.bus if network is not None else None
    return bus if bus is not None else default


def by_decoder(jobs: Sequence[SampleJob]) -> list[tuple[list[int], Decoder]]:
    """Rows that share one decoder object and pillar count: one decode call each."""
    groups: dict[tuple[int, int], tuple[list[int], Decoder]] = {}
    for i, job in enumerate(jobs):
        channel = job.slot.channel
        key = (id(channel.decoder), channel.pillars)
        groups.setdefault(key, ([], channel.decoder))[0].append(i)
    return list(groups.values())
