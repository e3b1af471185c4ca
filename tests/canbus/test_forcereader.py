"""The bus-side force reader: force nodes' TPDOs -> force samples, as any master reads them."""

from __future__ import annotations

import configparser
import functools
import struct
from collections.abc import Callable
from pathlib import Path

import can
import canopen
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from canbus import codes
from canbus.master.forceframes import forces_to_mN
from canbus.master.forcenode import ForceNode
from canbus.master.patch_setup import tpdo_layouts
from canbus.od import eds_file, load_od
from canbus.pdo_codec import PdoCodec
from canbus.tools.attribution import KnownNode
from canbus.tools.forcereader import UNSPECIFIED, ForceNodeSpec, ForceReader, ForceSample
from canbus.tools.resistance_reader import ResistanceReader, ResistanceSample
from canbus.tools.sample_tracker import LIVE, LOST, STALE, WAITING, SampleTracker
from decoder.reasons import Reason
from tests.support.rigs.waiting import wait_until

NODE = ForceNode(65, 1)  # only packs frames: never attached to a bus


def _messages(frames: list[tuple[int, bytes]], t: float, dt: float = 1e-4) -> list[can.Message]:
    return [can.Message(arbitration_id=cob, data=data, timestamp=t + k * dt,
                        is_extended_id=False) for k, (cob, data) in enumerate(frames)]


def _known(*nodes: int, eds: str | Path = "skin-forces") -> ForceReader:
    """A reader told that ``nodes`` keep their EDS default COB-IDs (as a config says)."""
    return ForceReader([ForceNodeSpec(n, known=True) for n in nodes], eds=eds)


def _read(reader: ForceReader, messages: list[can.Message],
          now: float | None = None) -> list[ForceSample]:
    got: list[ForceSample] = []
    reader.on_sample(got.append)
    for msg in messages:
        reader.on_message_received(msg)
    reader.process(now)
    return got


def _press(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.round(rng.uniform(-3, 6, (9, 3)), 3)


@functools.cache
def _node_and_reader(node: int) -> tuple[ForceNode, ForceReader, list[ForceSample]]:
    reader, sink = _known(node), []
    reader.on_sample(sink.append)
    return ForceNode(node, node - 64), reader, sink


@settings(max_examples=60, deadline=None)
@given(force=arrays(np.float64, (9, 3), elements=st.floats(-40.0, 40.0)),
       valid=arrays(np.bool_, 9), complete=st.booleans(), node=st.sampled_from([65, 100, 127]))
def test_the_reader_gives_back_what_a_force_node_published(
        force: np.ndarray, valid: np.ndarray, complete: bool, node: int) -> None:
    publisher, reader, sink = _node_and_reader(node)
    sink.clear()
    reader.feed(_messages(publisher.frames(force, valid, complete), 10.0))
    (sample,) = sink
    mN, on_bus = forces_to_mN(force, valid)
    assert (sample.patch, sample.force_node) == (node - 64, node)
    np.testing.assert_array_equal(sample.valid, on_bus)
    np.testing.assert_array_equal(sample.force_N,
                                  np.where(on_bus[:, None], mN / 1000.0, 0.0))
    assert sample.complete == complete and sample.pdos_missing == 0
    np.testing.assert_array_equal(sample.reason, np.where(on_bus, 0, UNSPECIFIED))
    assert sample.timestamp == pytest.approx(10.0 + 7e-4)  # the 8th PDO's: the contact


@pytest.mark.parametrize("lost", range(7))
def test_a_lost_pdo_makes_one_partial_sample_and_never_mixes_two(lost: int) -> None:
    forces = [_press(k) for k in range(3)]
    valid = np.ones(9, dtype=bool)
    messages: list[can.Message] = []
    for k, f in enumerate(forces):
        frames = NODE.frames(f, valid, True)
        if k == 1:
            del frames[lost]
        messages += _messages(frames, 1.0 + 0.01 * k)
    a, b, c = _read(_known(65), messages)
    for sample, f in ((a, forces[0]), (c, forces[2])):
        assert sample.complete and sample.valid.all()
        np.testing.assert_array_equal(sample.force_N, f)
    assert not b.complete and b.pdos_missing == 1
    carried = np.zeros(27, dtype=bool)
    carried[4 * lost: 4 * lost + 4] = True  # TPDO n carries 0x2000:4n+1..4n+4 (TPDO 7: 3)
    hit = carried.reshape(9, 3).any(axis=1)
    np.testing.assert_array_equal(b.valid, ~hit)
    np.testing.assert_array_equal(b.reason, np.where(hit, Reason.MISSING, 0))
    np.testing.assert_array_equal(b.force_N[~hit], forces[1][~hit])  # B's own values


def test_pdos_in_cob_id_order_make_the_same_samples() -> None:
    f = _press(3)
    frames = sorted(NODE.frames(f, np.ones(9, bool), True))  # 1C1, 241, 2C1, 341, ...
    assert [cob for cob, _ in frames] != [cob for cob, _ in NODE.frames(f, np.ones(9, bool),
                                                                        True)]
    samples = _read(_known(65), _messages(frames, 1.0) + _messages(frames, 1.01))
    assert [s.complete for s in samples] == [True, True]
    np.testing.assert_array_equal(samples[1].force_N, f)


def _syncs(until: float, count: int = 4, period: float = 0.01) -> list[can.Message]:
    return [can.Message(arbitration_id=0x80, data=[k + 1], timestamp=until - period * k,
                        is_extended_id=False) for k in range(count - 1, -1, -1)]


def test_a_sender_held_up_mid_sample_still_makes_whole_samples() -> None:
    reader = _known(65)
    a, b = _press(10), _press(11)
    fa = NODE.frames(a, np.ones(9, bool), True)
    fb = NODE.frames(b, np.ones(9, bool), True)
    messages = [*_syncs(0.999), *_messages(fa[:3], 1.0), *_messages(fa[3:], 1.009),
                *_syncs(1.0095, 1), *_messages(fb, 1.0096)]  # A's tail, then B, at once
    samples = _read(reader, messages)
    assert reader.period_s() == pytest.approx(0.01)
    assert [s.complete for s in samples] == [True, True]
    np.testing.assert_array_equal(samples[0].force_N, a)
    np.testing.assert_array_equal(samples[1].force_N, b)


def test_a_frame_seen_twice_is_one_frame_but_other_bytes_end_the_sample() -> None:
    fa = NODE.frames(_press(12), np.ones(9, bool), True)
    fb = NODE.frames(_press(13), np.ones(9, bool), True)
    twice = [*fa[:3], fa[2], *fa[3:]]
    (sample,) = _read(_known(65), _messages(twice, 1.0))
    assert sample.complete
    # B's first PDO lost, and its third is one A already holds: A ends there
    first, second = _read(_known(65), [*_messages(fa[:3], 1.0),
                                               *_messages(fb[1:], 1.001)], now=1.05)
    assert (first.pdos_missing, second.pdos_missing) == (5, 1)
    assert not first.complete and not second.complete
    np.testing.assert_array_equal(second.valid, ~np.isin(np.arange(9), [0, 1]))


def test_samples_without_their_first_pdo_stay_apart_and_open_ones_close_by_bus_time() -> None:
    reader = _known(65)
    fa = NODE.frames(_press(14), np.ones(9, bool), True)
    fb = NODE.frames(_press(15), np.ones(9, bool), True)
    got = _read(reader, [*_syncs(0.999), *_messages(fa[1:3], 1.0), *_messages(fb[3:], 1.01)])
    assert [s.pdos_missing for s in got] == [6]  # B's frames came 10 ms after A's began
    assert _read(reader, [], now=1.017) == []  # B, open 7 ms: less than 80 % of a period
    assert [s.pdos_missing for s in _read(reader, [], now=1.019)] == [3]
    reader.feed(_messages(fa[:2], 1.03))  # with its first PDO: open for two periods
    assert _read(reader, [], now=1.045) == []
    assert [s.pdos_missing for s in _read(reader, [], now=1.051)] == [6]
    status = reader.snapshot(1.06).patches[1]
    assert (status.samples, status.incomplete, status.partial) == (3, 3, 3)


def test_only_the_frames_a_reader_needs_are_copied() -> None:
    reader = _known(65)
    for cob in (0x181, 0x1C2, 0x701, 0x5C2):  # a patch PDO, another node's, heartbeat, SDO
        reader.on_message_received(can.Message(arbitration_id=cob, data=b"\0" * 8,
                                               is_extended_id=False))
    assert reader.received == 4 and len(reader._pending) == 0
    reader.on_message_received(can.Message(arbitration_id=0x5C1, data=b"\0" * 8,
                                           is_extended_id=False))
    assert len(reader._pending) == 1  # its SDO: a master may remap it


def _until(condition: Callable[[], bool], timeout: float = 30.0) -> None:
    wait_until(condition, what="the reader caught up", timeout=timeout)


def test_a_remap_and_the_source_patch_read_by_sdo_are_followed() -> None:
    channel = "reader-remap"
    device, master = canopen.Network(), canopen.Network()
    for net in (device, master):
        net.NOTIFIER_CYCLE = 0.05
        net.connect(interface="virtual", channel=channel)
    node = ForceNode(70, 5)
    node.attach(device)
    remote = canopen.RemoteNode(70, load_od("skin-forces", 70))
    master.add_node(remote)
    reader = _known(70)
    got: list[ForceSample] = []
    reader.on_sample(got.append)
    try:
        with can.Bus(interface="virtual", channel=channel) as listen, \
                can.Bus(interface="virtual", channel=channel) as sender:
            notifier = can.Notifier(listen, [reader], timeout=0.05)
            try:
                assert remote.sdo.upload(0x2001, 0) == b"\x05"
                # TPDO 6 carries the taxel status instead of taxel 6 z and taxel 7
                remote.sdo.download(0x1805, 1, struct.pack("<I", 0x8000_0000 | 0x346))
                remote.sdo.download(0x1A05, 0, b"\x00")
                for k in range(8):
                    remote.sdo.download(0x1A05, k + 1, struct.pack("<I", 0x2004_0008
                                                                   | (k + 1) << 8))
                remote.sdo.download(0x1A05, 0, b"\x08")
                remote.sdo.download(0x1805, 1, struct.pack("<I", 0x346))
                force = _press(5)
                valid = np.ones(9, dtype=bool)
                valid[2] = False
                reason = np.where(valid, 0, Reason.OPEN)
                for cob, data in node.frames(force, valid, True, reason=reason):
                    sender.send(can.Message(arbitration_id=cob, data=data,
                                            is_extended_id=False))
                _until(lambda: reader.received >= 24 + 7)
            finally:
                notifier.stop()
    finally:
        device.disconnect()
        master.disconnect()
    (sample,) = got
    assert sample.patch == 5  # 0x2001 as read, not the default 70 - 64
    assert sample.complete
    expected_valid = valid.copy()
    expected_valid[[6, 7]] = False  # no longer carried
    np.testing.assert_array_equal(sample.valid, expected_valid)
    assert sample.reason[2] == Reason.OPEN  # from 0x2004, now on the bus
    assert sample.reason[6] == sample.reason[7] == UNSPECIFIED
    np.testing.assert_array_equal(sample.force_N[expected_valid], force[expected_valid])


def test_pinned_cob_ids_and_patches_from_a_config() -> None:
    cob_ids = (0x1E0, 0x1E1, 0x1E2, 0x1E3, 0x1E4, 0x1E5, 0x1E6, 0x1E7)
    f = _press(6)
    frames = [(cob_ids[n], data)
              for n, (_, data) in enumerate(ForceNode(100, 3).frames(f, np.ones(9, bool), True))]
    (sample,) = _read(ForceReader([ForceNodeSpec(100, 3, cob_ids)]), _messages(frames, 2.0))
    assert (sample.patch, sample.force_node, sample.complete) == (3, 100, True)
    np.testing.assert_array_equal(sample.force_N, f)


def _fd_force_eds(path: Path) -> Path:
    """skin-forces.eds as a CAN FD force node: TPDO 1 carries 27 forces, 0x2005 and a SYNC
    counter byte 0x2006 (57 bytes); TPDO 2..8 are invalid."""
    eds = configparser.ConfigParser(interpolation=None)
    eds.optionxform = str  # type: ignore[assignment,method-assign]
    with eds_file("skin-forces") as shipped:
        eds.read(shipped, encoding="utf-8")
    entries = [0x2000_0010 | s << 8 for s in range(1, 28)] + [0x2005_0010, 0x2006_0008]
    eds["1A00"]["SubNumber"] = str(len(entries) + 1)
    eds["1A00sub0"]["DefaultValue"] = str(len(entries))
    del eds["1A00sub0"]["HighLimit"]
    for k, raw in enumerate(entries, start=1):
        eds[f"1A00sub{k:X}"] = {"ParameterName": f"Application object {k}", "ObjectType": "0x7",
                                "DataType": "0x0007", "AccessType": "rw",
                                "DefaultValue": f"0x{raw:08X}", "PDOMapping": "0"}
    for n in range(1, 8):
        eds[f"18{n:02X}sub1"]["DefaultValue"] = "0x80000000"
    eds["2006"] = {"ParameterName": "SYNC counter answered", "ObjectType": "0x7",
                   "DataType": "0x0005", "AccessType": "ro", "DefaultValue": "0",
                   "PDOMapping": "1"}
    optional = eds["OptionalObjects"]
    count = int(optional["SupportedObjects"])
    optional[str(count + 1)] = "0x2006"
    optional["SupportedObjects"] = str(count + 1)
    with path.open("w", encoding="utf-8") as handle:
        eds.write(handle, space_around_delimiters=False)
    return path


def test_a_can_fd_force_pdo_with_the_whole_sample_needs_only_its_eds(tmp_path: Path) -> None:
    eds = _fd_force_eds(tmp_path / "fd-forces.eds")
    reader = _known(65, eds=eds)
    layout = reader.assembly(65).layouts
    assert [(lay.cob_id, lay.size) for lay in layout] == [(0x1C1, 57)]
    f = _press(7)
    valid = np.ones(9, dtype=bool)
    valid[5] = False
    mN, on_bus = forces_to_mN(f, valid)
    bits = int(np.sum(on_bus.astype(int) << np.arange(9))) | 0x8000
    payload = struct.pack("<27hHB", *mN.reshape(-1).tolist(), bits, 17).ljust(64, b"\0")
    msg = can.Message(arbitration_id=0x1C1, data=payload, is_fd=True, timestamp=3.0,
                      is_extended_id=False)
    (sample,) = _read(reader, [msg])
    assert sample.complete and sample.sync_counter == 17 and sample.pdos_missing == 0
    np.testing.assert_array_equal(sample.valid, on_bus)
    np.testing.assert_array_equal(sample.force_N, np.where(on_bus[:, None], mN / 1000, 0.0))


def test_the_tracker_counts_rate_completeness_and_states() -> None:
    tracker = SampleTracker(window_s=1.0, stale_s=0.25, lost_s=2.0)
    tracker.expect(4, 68)
    assert tracker.status(0.0)[4].state == WAITING
    ok = np.ones(9, dtype=bool)
    for k in range(200):  # 2 s at 100 Hz, every 10th incomplete
        tracker.add(ForceSample(4, 68, 10.0 + 0.01 * k, np.zeros((9, 3)), ok,
                                np.zeros(9, np.uint8), k % 10 != 0, 0), partial=k % 10 == 0)
    s = tracker.status(11.995)[4]
    assert (s.samples, s.incomplete, s.partial, s.state) == (200, 20, 20, LIVE)
    assert s.rate_hz == pytest.approx(100.0) and s.complete_pct == pytest.approx(90.0)
    assert tracker.status(12.3)[4].state == STALE
    assert tracker.status(14.0)[4].state == LOST
    assert tracker.status(14.0)[4].rate_hz == 0.0
    tracker.add(ForceSample(4, 68, 14.0, np.zeros((9, 3)), np.zeros(9, bool),
                            np.full(9, Reason.MISSING, np.uint8), False, 7))
    assert tracker.status(14.1)[4].state == LIVE  # the host's withdrawal, just now
    assert tracker.status(14.3)[4].state == LOST  # ... and nothing since: lost


def test_the_resistance_reader_reads_a_patch_s_codes_in_ohms() -> None:
    layouts = tpdo_layouts(3, "xyz")
    codec = PdoCodec(layouts, load_od("skin-patch", 3))
    rng = np.random.default_rng(0)
    ohm = rng.uniform(900, 1500, (9, 3))
    code = codes.resistance_to_code(ohm, 0.05)
    code[4, 1] = codes.OPEN
    code[7, 0] = codes.SHORT
    payloads = codec.pack(code.reshape(1, 27))[0]
    # as the patch sends an answer: ascending COB-ID, TPDO 1, 5, 2, 6, 3, 7, 4
    frames = sorted((lay.cob_id, bytes(payloads[n][:lay.size])) for n, lay in enumerate(layouts))
    reader = ResistanceReader([3], known=[KnownNode(3, "skin-patch")])
    got: list[ResistanceSample] = []
    reader.on_sample(got.append)
    sync = [(0x080, b"\x01")]  # a sample is a patch's answer to a SYNC (canbus.answers)
    reader.feed(_messages(sync + frames, 5.0) + _messages(sync + frames[:6], 5.01))
    whole, partial = got  # the second closed by the end of the frames
    np.testing.assert_array_equal(whole.resistance_ohm, codes.code_to_resistance(code, 0.05))
    assert (whole.cycle, whole.complete, partial.cycle, partial.complete) == (1, True, 2, False)
    assert (whole.timestamp, partial.timestamp) == (5.0, 5.01)  # their SYNCs'
    # TPDO 4, the last the patch sends, never came (taxel 4's codes 13..15); TPDO 7 did
    assert np.isnan(partial.resistance_ohm[4]).all()
    assert not np.isnan(partial.resistance_ohm[8]).any()
    assert whole.resistance_ohm[4, 1] == np.inf and whole.resistance_ohm[7, 0] == 0.0
