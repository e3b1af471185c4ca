"""One assembly of a patch's answers, one judgement everywhere (``canbus.answers``).

The same recording, read four ways: (a) the host's data plane fed frame by frame, each
SYNC opening its cycle as a listen-only host's SYNC follower opens it; (b) the sniffer
(``Sniffer`` as ``skin sniff --config`` builds it); (c) the view's raw resistances
(``recorded_resistances``, ``skin view --plot --raw``); (d) ``skin decode``
(``canbus.offline``: the forces of ``decode_recording``, the resistances of
``read_patch_samples``). They call the same (patch, cycle) samples complete, the forces of
(a) and (d) are the same bits, and so are the resistances of (c) and (d) wherever (d)
reads one; the taxels (d) has as MISSING are those with a pillar (c) has not (its PDO did
not come in the answer).

The recordings: two 3-axis patches answering SYNCs with answers late past the next SYNC,
frames lost, repeated at once (a CAN retransmission), copied again later with the same
or other bytes, swapped and cut short (Hypothesis), and a hand-made one with one of each
whose verdicts are spelt out. A recording of a live host run: ``test_sniff_host.py``.
"""

from __future__ import annotations

import dataclasses
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import can
import numpy as np
import pytest
from hypothesis import given, note, settings
from hypothesis import strategies as st

from canbus.master.dataplane import DataPlane, ForceFrame
from canbus.master.hostconfig import HostConfig, PatchConfig
from canbus.master.sync_producer import SyncFollower
from canbus.offline.decode import decode_recording
from canbus.offline.recorded import read_patch_samples
from canbus.tools.answer_reader import Answer
from canbus.tools.attribution import Attribution
from canbus.tools.pdo_dictionary import Dictionary
from canbus.tools.recorder import CandumpLogWriter
from canbus.tools.recording import Recording
from canbus.tools.services import ServiceDecoder
from canbus.tools.sniffer import Sniffer
from decoder.reasons import Reason
from decoder.registry import create_decoder
from skin.benchmarks.dataplane_rigs import SinkBus
from skin.commands.common.known_nodes import known_nodes
from skin.commands.view.sources import recorded_resistances
from tests.support.rigs.dataplane import Patch, load

PERIOD_S = 0.01
T0 = 1000.0  # SYNC k at T0 + k * PERIOD_S
HEARTBEAT_S = 0.05  # each patch beats every 50 ms: operational, as the listen-only host sees
CYCLES = 6
PDOS = 7  # a 3-axis answer
NODES = (1, 2)
CONFIG = HostConfig(patches=tuple(PatchConfig(n) for n in NODES), sync_period_ms=1000 * PERIOD_S,
                    heartbeat_ms=100)

Key = tuple[int, int]  # (patch, cycle)


def _sync(cycle: int, t: float) -> can.Message:
    return can.Message(timestamp=t, arbitration_id=0x080, data=[cycle % 240 + 1],
                       is_extended_id=False)


def _write(frames: list[can.Message], folder: Path) -> Path:
    """The recording: the frames in bus order (their timestamps never go back), SYNC k at
    T0 + k periods, a last SYNC after every answer, heartbeats every 50 ms."""
    end = max([T0 + (CYCLES + 1) * PERIOD_S, *(m.timestamp + 1e-4 for m in frames)])
    events = [(T0 + k * PERIOD_S, 0, _sync(k, T0 + k * PERIOD_S)) for k in range(1, CYCLES + 1)]
    events += [(end, 0, _sync(CYCLES + 1, end))]
    beats = np.arange(T0 - 0.005, end, HEARTBEAT_S)
    events += [(t, 1, can.Message(timestamp=t, arbitration_id=0x700 + n, data=[5],
                                  is_extended_id=False)) for t in beats for n in NODES]
    events += [(m.timestamp, 2, m) for m in frames]
    path = folder / "answers.log"
    with path.open("w", encoding="utf-8") as handle:
        writer = CandumpLogWriter(handle)
        for _, _, msg in sorted(events, key=lambda e: (e[0], e[1])):
            writer.on_message_received(msg)
        writer.stop()
    return path


# -- the four readers ----------------------------------------------------------------------

@dataclass
class Verdicts:
    """Each reader's samples, by (patch, cycle)."""

    plane: dict[Key, ForceFrame]
    sniffer: dict[Key, Answer]
    view: dict[Key, tuple[bool, float, np.ndarray]]  # complete, SYNC time, (9, 3) ohm
    decode: dict[Key, ForceFrame]
    readings: dict[Key, tuple[bool, float, np.ndarray, np.ndarray]]  # ..., ohm, reasons

    def complete(self) -> dict[str, set[Key]]:
        return {"data plane": {k for k, f in self.plane.items() if f.complete},
                "sniffer": {k for k, a in self.sniffer.items() if a.complete},
                "view": {k for k, v in self.view.items() if v[0]},
                "skin decode": {k for k, f in self.decode.items() if f.complete},
                "skin decode's readings": {k for k, r in self.readings.items() if r[0]}}


class PlaneRig:
    """The host's data plane on a sink, channels for the patches, force nodes publishing."""

    def __init__(self) -> None:
        self.decoder = create_decoder("analytic")
        self.patches = [Patch(n) for n in NODES]
        self.sink = SinkBus()
        import canopen

        self.network = canopen.Network(self.sink)
        for patch in self.patches:
            patch.force_node.attach(self.network)
            patch.force_node.start()

    def read(self, path: Path, order: str) -> dict[Key, ForceFrame]:
        """The data plane fed the recording frame by frame, as the listen-only host's
        notifier hands them on: a patch's PDO to the data plane, the rest to the SYNC
        follower (a SYNC opens its cycle at once); no SYNC window (a listen-only host's)."""
        plane = DataPlane(self.sink, sync_window_s=0.0, background=False)
        for patch in self.patches:
            plane.add_channel(dataclasses.replace(patch.channel(self.decoder),
                                                  answer_order=order))
        out: list[ForceFrame] = []
        plane.subscribe(out.extend)
        follower = SyncFollower(plane.on_sync)
        try:
            with Recording(path) as recording:
                for msg in recording:
                    if not plane.take(msg):
                        follower.on_message_received(msg)
            plane.flush()
        finally:
            plane.stop()
        return _unique({(f.patch, f.cycle): f for f in out}, out)

    def close(self) -> None:
        for patch in self.patches:
            patch.force_node.detach()
        self.sink.shutdown()


def _unique(by_key: dict[Key, object], samples: list) -> dict:
    assert len(by_key) == len(samples), "two samples of one patch and cycle"
    return by_key


def _sniffed(path: Path, config: HostConfig) -> dict[Key, Answer]:
    """As ``skin sniff --config`` builds its sniffer."""
    answers: list[Answer] = []
    sniffer = Sniffer(ServiceDecoder(attribution=Attribution(Dictionary(),
                                                             known_nodes(config))),
                      on_answer=answers.append,
                      answer_orders={p.node_id: p.answer_order for p in config.patches})
    with Recording(path) as recording:
        for msg in recording:
            sniffer.on_message_received(msg)
    return _unique({(a.node_id, a.cycle): a for a in answers}, answers)


def _viewed(path: Path, config: HostConfig) -> dict[Key, tuple[bool, float, np.ndarray]]:
    out = {}
    for node in NODES:
        samples = recorded_resistances(path, node, config=config)
        assert all(s.cycle is not None for s in samples)
        out |= _unique({(node, s.cycle or 0): (s.complete, s.timestamp, s.resistance_ohm)
                        for s in samples}, samples)
    return out


def _readings(path: Path, order: str) -> dict[Key, tuple[bool, float, np.ndarray, np.ndarray]]:
    recorded = read_patch_samples(path, NODES, answer_order=order)
    out = {}
    for node, p in recorded.patches.items():
        for k, cycle in enumerate(p.cycle.tolist()):
            out[(node, cycle)] = (bool(p.complete[k]), float(p.time_s[k]), p.resistance_ohm[k],
                                  p.reason[k])
    return out


def _read(rig: PlaneRig, path: Path, order: str = "cob-id") -> Verdicts:
    """Every reader's samples; the patches send an answer's TPDOs in ``order``."""
    config = dataclasses.replace(CONFIG, patches=tuple(
        dataclasses.replace(p, answer_order=order) for p in CONFIG.patches))
    decoded = decode_recording(path, config)
    return Verdicts(rig.read(path, order), _sniffed(path, config), _viewed(path, config),
                    _unique({(f.patch, f.cycle): f for f in decoded}, decoded),
                    _readings(path, order))


def _assert_agree(v: Verdicts) -> None:
    complete = v.complete()
    want = complete["data plane"]
    for reader, got in complete.items():
        assert got == want, (reader, sorted(got ^ want))
    every = {(n, c) for n in NODES for c in range(1, CYCLES + 2)}  # one sample per SYNC
    assert set(v.plane) == set(v.decode) == set(v.view) == set(v.readings) == every
    assert set(v.sniffer) == {(n, c) for n, c in every if c <= CYCLES}  # the last stays open
    for key, frame in v.plane.items():  # the same code on the same machine: the same bits
        other = v.decode[key]
        np.testing.assert_array_equal(frame.force_N, other.force_N, err_msg=str(key))
        np.testing.assert_array_equal(frame.valid, other.valid, err_msg=str(key))
        np.testing.assert_array_equal(frame.reason, other.reason, err_msg=str(key))
    for key, (_, sync_time, ohm) in v.view.items():
        _, time_s, readings, reason = v.readings[key]
        assert sync_time == time_s, key
        read = reason == Reason.OK
        np.testing.assert_array_equal(ohm[read], readings[read], err_msg=str(key))
        # a pillar whose PDO was missing: a taxel MISSING (the data plane masks taxels)
        np.testing.assert_array_equal(np.isnan(ohm).any(axis=1), reason == Reason.MISSING,
                                      err_msg=str(key))


@pytest.fixture(scope="module")
def rig() -> Iterator[PlaneRig]:
    built = PlaneRig()
    yield built
    built.close()


# -- a recording with one of each ------------------------------------------------------------

def _answer(patch: Patch, cycle: int, start: float, gap: float = 1e-4) -> list[can.Message]:
    frames = patch.frames(load(0.2 + 0.1 * cycle + 0.05 * patch.node.node_id), cycle)
    for k, msg in enumerate(frames):
        msg.timestamp = start + k * gap
    return frames


def test_late_repeated_and_missing_answers_are_judged_alike_everywhere(rig: PlaneRig) -> None:
    a, b = rig.patches
    sync = [T0 + k * PERIOD_S for k in range(CYCLES + 1)]
    frames = _answer(a, 1, sync[1] + 1e-3) + _answer(b, 1, sync[1] + 2e-3)
    retransmitted = _answer(a, 2, sync[2] + 1e-3)
    retransmitted.insert(3, retransmitted[2])  # the same frame, the same bytes, at once
    frames += retransmitted
    late = _answer(b, 2, sync[2] + 0.8 * PERIOD_S, gap=0.1 * PERIOD_S)  # runs past SYNC 3
    frames += late + _answer(b, 3, late[-1].timestamp + 1e-4)
    lost = _answer(a, 3, sync[3] + 1e-3)
    del lost[4]
    frames += lost
    whole_but_late = _answer(a, 4, sync[5] + 1e-3)  # all of it after SYNC 5: cycle 5's
    frames += whole_but_late + _answer(a, 5, whole_but_late[-1].timestamp + 1e-4)
    doubled = _answer(b, 5, sync[5] + 1e-3)
    doubled.insert(5, can.Message(timestamp=doubled[4].timestamp, is_extended_id=False,
                                  arbitration_id=doubled[1].arbitration_id, data=bytes(8)))
    frames += doubled + _answer(a, 6, sync[6] + 1e-3) + _answer(b, 6, sync[6] + 2e-3)
    with tempfile.TemporaryDirectory() as folder:
        verdicts = _read(rig, _write(sorted(frames, key=lambda m: m.timestamp), Path(folder)))
    _assert_agree(verdicts)
    assert verdicts.complete()["sniffer"] == {
        (1, 1), (2, 1),  # whole
        (1, 2),  # a retransmission changes nothing
        # (2, 2) ran past SYNC 3: its head is cycle 2's, incomplete; its tail late in 3,
        (2, 3),  # ... before patch 2's own answer to SYNC 3
        # (1, 3) lost its fifth TPDO; (1, 4) unanswered: its answer came after SYNC 5,
        (1, 5),  # ... whole: a stale answer classic CAN cannot tell from a prompt one
        # (2, 5): TPDO 2 again, other bytes, after TPDO 5: the answer ended there
        (1, 6), (2, 6)}


def test_patches_that_send_in_tpdo_order_are_judged_in_that_order_everywhere(
        rig: PlaneRig) -> None:
    """A config's ``answer_order = "tpdo"`` (one transmit FIFO) is every reader's: an answer
    in TPDO order is whole, one in COB-ID order broken at its second frame."""
    frames = []
    for k in range(1, CYCLES + 1):
        for patch in rig.patches:
            answer = _answer(patch, k, T0 + k * PERIOD_S + 1e-3 * patch.node.node_id)
            times = [msg.timestamp for msg in answer]
            if patch.node.node_id == 1:  # in TPDO order: by position in the mapping
                answer.sort(key=lambda m: list(patch.codec.cob_ids).index(m.arbitration_id))
            for msg, t in zip(answer, times, strict=True):
                msg.timestamp = t
            frames += answer
    with tempfile.TemporaryDirectory() as folder:
        verdicts = _read(rig, _write(sorted(frames, key=lambda m: m.timestamp), Path(folder)),
                         "tpdo")
    _assert_agree(verdicts)
    assert verdicts.complete()["view"] == {(1, k) for k in range(1, CYCLES + 1)}


# -- the property ----------------------------------------------------------------------------

_FRAME = st.integers(0, CYCLES * PDOS - 1)  # a patch's frame, in the order it sends them


def _some(items: st.SearchStrategy, most: int) -> st.SearchStrategy:
    """None half the time, else up to ``most`` of ``items``."""
    return st.one_of(st.just(()), st.lists(items, min_size=1, max_size=most))


_plans = st.fixed_dictionaries({
    # when each answer starts after its SYNC: mostly early in the period, some up to two
    # and a half periods late
    "delay": st.lists(st.one_of(st.floats(0.0, 0.3 * PERIOD_S), st.floats(0.0, 2.5 * PERIOD_S)),
                      min_size=CYCLES, max_size=CYCLES),
    "gap": st.floats(2e-5, 1e-3),  # between frames of one answer
    "lost": _some(_FRAME, 6),
    "repeated": _some(_FRAME, 4),  # again at once, the same bytes: a CAN retransmission
    "copied": _some(st.tuples(_FRAME, st.integers(1, 14), st.booleans()), 3),  # again, n
    # frames on, with the same or other bytes
    "swapped": _some(_FRAME, 3),  # frame i and the next swap places
    "short": _some(_FRAME, 2),  # cut short: malformed
})


def _stream(answers: list[list[can.Message]], plan: dict) -> list[can.Message]:
    """One patch's frames as they arrive: the patch sends its answers one after the other,
    each ``delay`` after its SYNC (a FIFO: not before the previous one is out); the way to
    the receiver loses, repeats, copies, swaps and cuts them; the receiver stamps them in
    the order they arrive."""
    sent: list[can.Message] = []
    t = 0.0
    for k, frames in enumerate(answers):
        t = max(t, T0 + (k + 1) * PERIOD_S + plan["delay"][k])
        for msg in frames:
            msg.timestamp = t
            t += plan["gap"]
            sent.append(msg)
    for i in plan["short"]:
        sent[i].data = sent[i].data[:5]
        sent[i].dlc = 5
    out: list[can.Message] = []
    for i, msg in enumerate(sent):
        if i not in plan["lost"]:
            out += [msg, msg] if i in plan["repeated"] else [msg]
    for i, later, other in plan["copied"]:
        if i < len(out):
            data = bytes([out[i].data[0] ^ 0xFF, *out[i].data[1:]]) if other and out[i].data \
                else out[i].data
            copy = can.Message(arbitration_id=out[i].arbitration_id, data=data,
                               is_extended_id=False)
            out.insert(min(i + later, len(out)), copy)
    for i in sorted(plan["swapped"]):
        if i + 1 < len(out):
            out[i], out[i + 1] = out[i + 1], out[i]
    arrived = 0.0
    stamped = []
    for msg in out:
        arrived = max(arrived, msg.timestamp)
        stamped.append(can.Message(timestamp=arrived, arbitration_id=msg.arbitration_id,
                                   data=msg.data, is_extended_id=False))
    return stamped


@settings(max_examples=40)
@given(plans=st.tuples(_plans, _plans), scales=st.permutations([0.1 * k for k in range(1, 13)]))
def test_every_reader_judges_each_sample_as_the_host_does(rig: PlaneRig, plans: tuple,
                                                           scales: list[float]) -> None:
    frames = []
    for p, (patch, plan) in enumerate(zip(rig.patches, plans, strict=True)):
        answers = [patch.frames(load(scales[p * CYCLES + k]), k + 1) for k in range(CYCLES)]
        frames += _stream(answers, plan)
    with tempfile.TemporaryDirectory() as folder:
        verdicts = _read(rig, _write(sorted(frames, key=lambda m: m.timestamp), Path(folder)))
    note(f"complete: {sorted(verdicts.complete()['data plane'])}")
    _assert_agree(verdicts)
