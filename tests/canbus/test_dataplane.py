# mypy: disable-error-code="no-untyped-call"
from __future__ import annotations

import queue
import threading
import time

import can
import canopen
import numpy as np
import pytest
from numpy.typing import ArrayLike

from canbus.codes import code_to_resistance, resistance_to_code
from canbus.device.nmt_slave import OPERATIONAL, STOPPED
from canbus.device.patch_server import PatchServer
from canbus.device.source import ArraySource
from canbus.master.dataplane import DataPlane, ForceFrame, PatchChannel
from canbus.master.forceframes import COMPLETE, NO_VALUE
from canbus.master.forcenode import ForceNode
from canbus.od import load_od
from canbus.pdo_codec import TPDO_MAP
from decoder.protocol import Decoded
from decoder.reasons import Reason
from decoder.registry import create_decoder
from skin.constants import DEFAULT_CONSTANTS
from skin.errors import ConfigError
from skin.tripod import resistance_from_force
from tests.support.rigs.dataplane import LSB, WINDOW_S, Host, Patch, consume, load, mN, sync_time
from tests.support.rigs.waiting import holds_for, wait_until


def test_complete_samples_decode_exactly_and_go_out_as_force_tpdos(host: Host) -> None:
    host.sync(1)
    a, b = host.patches
    host.feed(a.frames(load(), 1) + b.frames(load(0.5), 1))
    host.plane.publish_pending()  # the publishing thread's work, here in the test's thread
    assert [(f.patch, f.force_node, f.cycle, f.sync_counter, f.complete, f.published)
            for f in host.out] == [(1, 65, 1, 2, True, True), (2, 66, 1, 2, True, True)]
    for frame, patch in zip(host.out, host.patches, strict=True):
        expected = patch.expected(host.decoder)
        np.testing.assert_allclose(frame.force_N, expected.force_N[0], rtol=1e-12, atol=0)
        assert frame.valid.all() and not frame.reason.any() and frame.timestamp == sync_time(1)
    np.testing.assert_allclose(host.out[0].force_N, load(), atol=2e-3)  # the forces applied
    forces, bits = consume(host.published(65))
    assert forces == mN(host.out[0].force_N) and bits == COMPLETE | 0x1FF
    assert host.plane.stats.snapshot()["frames_out"] == 16  # 7 force PDOs + the contact


def test_lost_frame_makes_the_sample_incomplete_with_missing_taxels(host: Host) -> None:
    host.sync(1)
    a, b = host.patches
    frames = a.frames(load(), 1)
    assert frames[6].arbitration_id == 0x481  # the last of the answer: TPDO 4
    host.feed(frames[:6] + b.frames(load(), 1))  # a's TPDO 4 is lost
    host.plane.publish_pending()
    assert [f.patch for f in host.out] == [2]  # b is complete: published without waiting
    host.sync(2)  # closes cycle 1
    late = host.out[1]
    assert (late.patch, late.cycle, late.complete, late.published) == (1, 1, False, True)
    lost = a.carried(6)
    assert lost == [4, 5]
    assert (late.reason[lost] == Reason.MISSING).all() and not late.valid[lost].any()
    kept = [t for t in range(9) if t not in lost]
    np.testing.assert_allclose(late.force_N[kept], a.expected(host.decoder).force_N[0][kept],
                               rtol=1e-12)
    forces, bits = consume(host.published(65))
    assert forces[12:18] == [NO_VALUE] * 6 and forces[:12] == mN(late.force_N)[:12]
    assert bits == sum(1 << t for t in kept)  # bit 15 clear: incomplete
    assert host.plane.stats.incomplete_samples == 1


def test_a_frame_lost_inside_the_answer_ends_it(host: Host) -> None:
    """After a gap nothing proves the next frame is of the same answer: it is not taken."""
    host.sync(1)
    a = host.patches[0]
    frames = a.frames(load(), 1)
    host.feed(frames[:2] + frames[3:])  # the third frame is lost
    host.sync(2)
    sample = host.out[0]
    lost = sorted({t for place in range(2, 7) for t in a.carried(place)})
    assert not sample.complete and list(np.flatnonzero(~sample.valid)) == lost
    assert host.plane.stats.out_of_order_frames == 4


def test_duplicate_frame_is_not_trusted_and_ends_the_answer(host: Host) -> None:
    host.sync(1)
    a = host.patches[0]
    frames = a.frames(load(), 1)
    impostor = a.frames(load(0.3), 1)[3]
    host.feed([*frames[:4], impostor, *frames[4:]])  # the 4th frame twice, different data
    host.sync(2)
    sample = next(f for f in host.out if f.patch == 1)
    stats = host.plane.stats
    assert not sample.complete and stats.duplicate_frames == 1
    assert stats.out_of_order_frames == 3  # what followed the break is not taken
    lost = sorted({t for place in range(3, 7) for t in a.carried(place)})
    assert (sample.reason[lost] == Reason.MISSING).all()
    assert sample.valid.sum() == 9 - len(lost)


def test_the_same_frame_again_at_once_is_a_harmless_repeat(host: Host) -> None:
    """A CAN receiver gets a frame twice when its sender retransmits it."""
    host.sync(1)
    a = host.patches[0]
    frames = a.frames(load(), 1)
    host.feed([*frames[:4], frames[3], *frames[4:]])
    host.plane.publish_pending()
    assert host.out[0].complete and host.out[0].valid.all()
    assert host.plane.stats.duplicate_frames == 1


def test_late_frame_beyond_the_window_is_dropped(host: Host) -> None:
    host.sync(1)
    a = host.patches[0]
    frames = a.frames(load(), 1)
    frames[6].timestamp = sync_time(1) + WINDOW_S + 1e-3
    host.feed(frames)
    host.plane.publish_pending()
    assert not any(f.patch == 1 for f in host.out)
    host.sync(2)
    sample = next(f for f in host.out if f.patch == 1)
    assert not sample.complete and host.plane.stats.late_frames == 1
    assert (sample.reason[a.carried(6)] == Reason.MISSING).all()


def test_cycles_are_never_mixed(host: Host) -> None:
    a = host.patches[0]
    old, new = a.frames(load(), 1), a.frames(load(0.5), 2)
    expected_new = a.expected(host.decoder).force_N[0]
    host.sync(1)
    host.feed(old[:5])
    host.sync(2)  # SYNC 2 overtakes cycle 1's last two frames
    host.feed(old[5:] + new)
    host.plane.publish_pending()
    first, second = (f for f in host.out if f.patch == 1)
    assert (first.cycle, first.complete, second.cycle, second.complete) == (1, False, 2, True)
    assert host.plane.stats.late_frames == 2
    np.testing.assert_allclose(second.force_N, expected_new, rtol=1e-12)
    missing = sorted(set(a.carried(5) + a.carried(6)))
    assert (first.reason[missing] == Reason.MISSING).all()
    assert first.valid.sum() == 9 - len(missing)


def test_frames_of_the_next_sync_before_on_sync_are_kept_for_it(host: Host) -> None:
    a = host.patches[0]
    host.sync(1)
    host.feed(a.frames(load(), 1))
    host.feed(a.frames(load(0.5), 2))  # the patch answered SYNC 2 before on_sync(2) ran
    host.sync(2)
    host.plane.publish_pending()
    assert [(f.cycle, f.complete) for f in host.out if f.patch == 1] == [(1, True), (2, True)]
    assert host.plane.stats.late_frames == 0


def test_faulty_taxels_are_masked_and_neighbours_decode(host: Host) -> None:
    a = host.patches[0]
    host.plane.channel(1).masked[4] = True  # the host learnt taxel 4 is faulty (EMCY)
    host.sync(1)
    host.feed(a.frames(load(), 1, t7=np.inf))  # and taxel 7's pillar z is open
    host.plane.publish_pending()
    sample = host.out[0]
    assert sample.reason[4] == Reason.FAULTY and sample.reason[7] == Reason.OPEN
    assert sample.complete and sample.published
    good = [0, 1, 2, 3, 5, 6, 8]
    assert sample.valid[good].all() and not sample.valid[[4, 7]].any()
    assert not sample.force_N[[4, 7]].any()
    np.testing.assert_allclose(sample.force_N[good], load()[good], atol=2e-3)
    forces, bits = consume(host.published(65))
    assert forces[12:15] == [NO_VALUE] * 3 and forces[21:24] == [NO_VALUE] * 3
    assert bits == COMPLETE | 0x1FF & ~(1 << 4 | 1 << 7)


def test_unknown_frames_are_counted_and_ignored(host: Host) -> None:
    host.sync(1)
    frames = host.patches[0].frames(load(), 1)
    strangers = [can.Message(arbitration_id=0x123, data=bytes(8), is_extended_id=False),
                 can.Message(arbitration_id=0x181, data=bytes(8), is_extended_id=True),
                 can.Message(arbitration_id=0x181, is_remote_frame=True, is_extended_id=False)]
    host.feed(frames[:3] + strangers + frames[3:])
    host.plane.publish_pending()
    stats = host.plane.stats.snapshot()
    assert stats["unknown_frames"] == 3 and stats["frames_in"] == 7
    assert host.out[0].complete and host.out[0].valid.all()


def test_short_frame_is_malformed() -> None:
    host = Host()
    try:
        host.sync(1)
        frames = host.patches[0].frames(load(), 1)
        frames[2].data = frames[2].data[:6]
        frames[2].dlc = 6
        host.feed(frames)
        host.sync(2)
        assert host.plane.stats.malformed_frames == 1 and not host.out[0].complete
    finally:
        host.close()


def test_silent_and_removed_patches(host: Host) -> None:
    host.sync(1)
    host.feed(host.patches[0].frames(load(), 1))
    host.sync(2)  # patch 2 sent nothing in cycle 1: one all-invalid sample all the same
    silent = next(f for f in host.out if f.patch == 2)
    assert not silent.complete and silent.published
    assert (silent.reason == Reason.MISSING).all()
    forces, bits = consume(host.published(66), 66)
    assert forces == [NO_VALUE] * 27 and bits == 0
    host.plane.remove_channel(2)
    host.feed(host.patches[1].frames(load(), 2))
    assert host.plane.stats.unknown_frames == 7
    with pytest.raises(ConfigError, match="no channel for patch 2"):
        host.plane.channel(2)


def test_raw_sample_and_scale(host: Host) -> None:
    a = host.patches[0]
    assert host.plane.raw_sample(1) is None
    host.sync(1)
    host.feed(a.frames(load(), 1))
    host.plane.publish_pending()
    raw = host.plane.raw_sample(1)
    assert raw is not None
    np.testing.assert_array_equal(raw, code_to_resistance(a.node.codes, LSB))
    # A drift of +1 % on every pillar, tared away by scale = r0_ref / baseline.
    host.plane.channel(1).scale = np.full((9, 3), 1 / 1.01)
    host.sync(2)
    r = resistance_from_force(load(), DEFAULT_CONSTANTS) * 1.01
    a.node.update(r)
    host.feed(a.answer(a.codec.pack(a.node.values())[0], 2))
    host.plane.publish_pending()
    np.testing.assert_allclose(host.out[-1].force_N, load(), atol=3e-3)


class CountingDecoder:
    """Delegates to the analytic decoder and records the batch shapes it is given."""

    name = "counting"

    def __init__(self) -> None:
        self.inner = create_decoder("analytic")
        self.calls: list[tuple[int, ...]] = []

    def decode(self, resistance_ohm: ArrayLike) -> Decoded:
        r = np.asarray(resistance_ohm)
        self.calls.append(r.shape)
        decoded: Decoded = self.inner.decode(r)
        return decoded


def test_one_decode_call_per_decoder_object() -> None:
    counting = CountingDecoder()
    host = Host(counting)
    try:
        host.sync(1)
        host.feed(host.patches[0].frames(load(), 1) + host.patches[1].frames(load(), 1))
        host.plane.publish_pending()
        assert counting.calls == [(2, 9, 3)]
        assert [f.complete for f in host.out] == [True, True]
    finally:
        host.close()


def test_codes_at_odd_bytes_decode_like_the_default_mapping(host: Host) -> None:
    """Patch 2's TPDO 1 maps its status byte first, so its codes start at odd bytes
    (code 4 moves to TPDO 7)."""
    shifted = host.patches[1].node
    for pdo, entries in ((0, [0x20040108, 0x20000110, 0x20000210, 0x20000310]),
                         (6, [0x20001910, 0x20001A10, 0x20001B10, 0x20000410])):
        shifted.store.store(TPDO_MAP + pdo, 0, len(entries))
        for s, raw in enumerate(entries, start=1):
            shifted.store.store(TPDO_MAP + pdo, s, raw)
    shifted.tpdo.reset()
    host.plane.add_channel(host.patches[1].channel(host.decoder))
    host.sync(1)
    host.feed(host.patches[0].frames(load(), 1) + host.patches[1].frames(load(), 1))
    host.plane.publish_pending()
    assert [f.complete for f in host.out] == [True, True]
    for frame, patch in zip(host.out, host.patches, strict=True):
        expected = patch.expected(host.decoder)
        np.testing.assert_allclose(frame.force_N, expected.force_N[0], rtol=1e-12, atol=0)
    np.testing.assert_array_equal(host.out[0].force_N, host.out[1].force_N)


def test_z_only_patches() -> None:
    host = Host(mode="z")
    try:
        host.sync(1)
        load = np.zeros((9, 3))
        load[:, 2] = np.linspace(0.2, 4.5, 9)
        host.feed(host.patches[0].frames(load, 1))
        host.plane.publish_pending()
        assert host.out[0].complete and host.out[0].valid.all()
        np.testing.assert_allclose(host.out[0].force_N, load, atol=2e-3)
        assert len(host.published(65)) == 8  # the forces of a z patch are 3-axis still
    finally:
        host.close()


def test_identifier_clashes_and_incomplete_mappings_are_refused(host: Host) -> None:
    a = host.patches[0]
    with pytest.raises(ConfigError, match="share COB-ID"):
        host.plane.add_channel(PatchChannel(3, a.codec, 3, LSB, host.decoder,
                                            ForceNode(67, 3, heartbeat_ms=0)))
    with pytest.raises(ConfigError, match="share COB-ID"):  # force node 2 sends on 0x182...
        host.plane.add_channel(PatchChannel(3, Patch(3).codec, 3, LSB, host.decoder,
                                            ForceNode(2, 3, heartbeat_ms=0)))
    z = Patch(3, mode="z")
    with pytest.raises(ConfigError, match="do not map every 0x2000 code of 3 pillar"):
        host.plane.add_channel(PatchChannel(3, z.codec, 3, LSB, host.decoder, z.force_node))
    with pytest.raises(ConfigError, match="sync_window_s"):
        DataPlane(host.sink, sync_window_s=-1.0, background=False)


# -- end to end: patch nodes, the data plane's thread, a canopen consumer, one virtual bus -----

def _network(channel: str) -> canopen.Network:
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05
    return net.connect(interface="virtual", channel=channel)


def test_end_to_end_published_before_the_window_closes(request: pytest.FixtureRequest) -> None:
    channel = request.node.name
    force = np.stack([load(s) for s in (0.2, 1.0, 0.6)])  # samples 0, 1, 2
    samples = np.stack([force, force[:, ::-1]], axis=1)  # patch 2 sees the mirrored loads
    resistance = resistance_from_force(samples, DEFAULT_CONSTANTS)
    device, host_net, consumer = _network(channel), _network(channel), _network(channel)
    server = PatchServer(device, ArraySource(resistance, (1, 2)))
    decoder = create_decoder("analytic")
    window = 120.0  # frames are awaited 30 s at most: nothing may wait for it to close
    assert host_net.bus is not None
    plane = DataPlane(host_net.bus, sync_window_s=window)
    got: queue.Queue[tuple[float, ForceFrame]] = queue.Queue()

    def on_frames(frames: list[ForceFrame]) -> None:
        for f in frames:
            got.put((time.time(), f))

    plane.subscribe(on_frames)
    force_nodes = []
    try:
        server.start()
        for node in server.nodes:
            force_node = ForceNode(node.node_id + 64, node.node_id, heartbeat_ms=0)
            force_node.attach(host_net)
            force_node.start()
            force_nodes.append(force_node)
            plane.add_channel(PatchChannel(node.node_id, node.tpdo.codec, node.pillars, LSB,
                                           decoder, force_node))
        assert host_net.notifier is not None
        host_net.notifier.add_listener(plane)
        remote = consumer.add_node(canopen.RemoteNode(65, load_od("skin-forces", 65)))
        remote.tpdo.read(from_od=True)
        received = threading.Event()
        remote.tpdo[7].add_callback(lambda _: received.set())
        host_net.nmt.send_command(0x01)  # start every patch
        wait_until(lambda: all(n.state == OPERATIONAL for n in server.nodes),
                   what="the patches operational")

        plane.on_sync(1, 0, time.time())
        host_net.sync.transmit()
        frames = [got.get(timeout=30.0), got.get(timeout=30.0)]  # well inside the window
        by_patch = {f.patch: f for _, f in frames}
        assert sorted(by_patch) == [1, 2] and all(f.complete and f.published for _, f in frames)
        for p in (1, 2):
            codes = resistance_to_code(resistance[1, p - 1], LSB)
            expected = decoder.decode(code_to_resistance(codes, LSB)[None]).force_N[0]
            np.testing.assert_allclose(by_patch[p].force_N, expected, rtol=1e-12)
        assert received.wait(30.0)
        sent = [v.raw for n in range(1, 8) for v in remote.tpdo[n]][:27]
        assert sent == mN(by_patch[1].force_N)
        assert remote.tpdo[7]["Valid taxels"].raw == COMPLETE | 0x1FF

        remote.nmt.send_command(0x02)  # another master stops force node 65
        wait_until(lambda: force_nodes[0].state == STOPPED, what="force node 65 stopped")
        received.clear()
        plane.on_sync(2, 0, time.time())
        host_net.sync.transmit()
        frames = [got.get(timeout=30.0), got.get(timeout=30.0)]
        published = {f.patch: f.published for _, f in frames}
        assert published == {1: False, 2: True}  # 65 is silent, 66 still publishes
        assert not received.wait(0.2)
    finally:
        plane.flush()
        plane.stop()
        server.stop()
        for force_node in force_nodes:
            force_node.detach()
        for net in (consumer, host_net, device):
            net.disconnect()


def test_the_steady_state_begins_with_the_first_cycle_every_patch_is_online(host: Host) -> None:
    """Samples made while a patch is still being set up are not the steady state's; from
    the first cycle with every patch online on, every sample is, a lost patch's too."""
    a = host.patches[0]
    plane = host.plane
    plane.set_online(2, False)  # patch 2 still configuring
    for k in (1, 2):
        host.sync(k)
        host.feed(a.frames(load(0.5), k))
    assert plane.steady_from_cycle is None
    plane.set_online(2, True)
    for k in (3, 4):
        host.sync(k)
        for patch in host.patches:
            host.feed(patch.frames(load(0.5), k))
    plane.set_online(2, False)  # lost in the steady state: its samples count against it
    host.sync(5)
    host.feed(a.frames(load(0.5), 5))
    plane.flush()
    assert plane.steady_from_cycle == 3
    stats = plane.stats
    assert (stats.samples, stats.complete_samples) == (10, 7)
    assert (stats.steady_samples, stats.steady_complete_samples) == (6, 5)


def _publishing_host(hold_s: float) -> Host:
    """The rig's patches on a data plane that publishes on its own thread."""
    host = Host()
    host.plane.stop()
    host.plane = DataPlane(host.sink, sync_window_s=WINDOW_S, publish_hold_s=hold_s)
    for patch in host.patches:
        host.plane.add_channel(patch.channel(host.decoder))
    host.plane.subscribe(host.out.extend)
    return host


def test_the_patches_of_one_cycle_are_published_in_one_round() -> None:
    """A ready sample waits for the cycle's other patches (each round of decoding costs
    its numpy calls whatever its size), and goes with them as soon as they answered."""
    host = _publishing_host(hold_s=30.0)
    try:
        a, b = host.patches
        host.sync(1)
        host.feed(a.frames(load(0.5), 1))
        holds_for(lambda: not host.out, 0.2, what="patch 1's sample held for patch 2")
        host.feed(b.frames(load(0.5), 1))
        wait_until(lambda: len(host.out) == 2, what="both samples published")
        assert host.plane.stats.batches == 1
    finally:
        host.close()


def test_a_held_sample_goes_after_the_hold_when_another_patch_is_silent() -> None:
    host = _publishing_host(hold_s=0.05)
    try:
        a = host.patches[0]
        host.sync(1)
        host.feed(a.frames(load(0.5), 1))  # patch 2 says nothing: still in the cycle
        wait_until(lambda: len(host.out) == 1, what="patch 1 published after the hold")
        assert host.out[0].patch == 1 and host.out[0].complete
    finally:
        host.close()
