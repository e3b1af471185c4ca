"""The host manager end to end on a virtual bus: simulated patches, each on its own canopen
Network (as separate devices would be), a spy bus that records every frame, and the host."""

from __future__ import annotations

import threading
from dataclasses import replace

import can
import canopen
import numpy as np
import pytest

from canbus import codes
from canbus.device.nmt_slave import PRE_OPERATIONAL
from canbus.device.patch_node import PatchNode
from canbus.device.source import ArraySource
from canbus.master.baseline import PatchLoadedError
from canbus.master.dataplane import ForceFrame
from canbus.master.host import HostManager
from canbus.master.hostconfig import DriftConfig, PatchConfig
from decoder.reasons import Reason
from decoder.registry import create_decoder
from sim import Simulator, load_scene
from skin.errors import BusError
from tests.support.rigs.host import (
    LSB,
    R0,
    WAIT_S,
    Rig,
    config,
    decode_force_pdos,
    eventually,
    expected,
    force_pdos,
    press,
    source,
)


def test_host_configures_patches_and_publishes_their_forces(rig: Rig) -> None:
    xyz = press({4: (0.3, -0.2, 2.0), 0: (0.0, 0.0, 0.5)})
    z = press({2: (0.0, 0.0, 1.5), 7: (0.0, 0.0, 3.0)}, pillars=1)
    rig.serve(1, source(1, xyz))
    rig.serve(2, source(2, z))
    host = rig.start(config(PatchConfig(1), PatchConfig(2, mode="z", force_node=80)))
    # start() returns once the patches found by the scan are configured
    assert {n: h.state for n, h in host.health().items()} == {1: "operational", 2: "operational"}
    frames = host.frames(timeout=WAIT_S)
    got: dict[int, ForceFrame] = {}
    for frame in frames:
        got.setdefault(frame.patch, frame)
        if len(got) == 2:
            break
    for node_id, resistance, force_node in ((1, xyz, 65), (2, z, 80)):
        frame = got[node_id]
        force, reason = expected(resistance)
        assert frame.force_node == force_node and frame.complete and frame.published
        assert frame.sync_counter == frame.cycle % 240 + 1
        np.testing.assert_allclose(frame.force_N, force, rtol=0, atol=1e-12)
        assert frame.valid.all() and not reason.any()
    assert abs(got[1].force_N[4, 2] - 2.0) < 0.01 and abs(got[2].force_N[7, 2] - 3.0) < 0.01
    # the patches were told: synchronous TPDOs of the decoder's mode, the heartbeat period
    node_1, node_2 = rig.servers[1][1].nodes[0], rig.servers[2][1].nodes[0]
    assert len(node_1.tpdo.codec.layouts) == 7 and len(node_2.tpdo.codec.layouts) == 3
    assert int(node_1.store.value(0x1017)) == int(node_2.store.value(0x1017)) == 200
    # the forces are on the bus as the force nodes' TPDOs: INTEGER16 mN + valid bits
    host.stop()
    for force_node, frame in ((65, got[1]), (80, got[2])):
        mN, valid = decode_force_pdos(force_pdos(rig.seen, force_node), force_node)
        np.testing.assert_array_equal(mN, np.rint(frame.force_N * 1000))
        assert valid == 0x81FF  # nine valid taxels + complete
    stats = host.stats()  # (how many are complete is the machine's: a stall makes one late)
    assert stats["samples"] >= stats["complete_samples"] > 0 and stats["malformed_frames"] == 0
    assert not rig.unknown


def test_a_silent_patch_is_lost_the_others_go_on_and_it_comes_back(rig: Rig) -> None:
    rests = {n: press({n: (0.0, 0.0, float(n))}, pillars=1) for n in (1, 2, 3)}
    for node_id, r in rests.items():
        rig.serve(node_id, source(node_id, r))
    host = rig.start(config(*(PatchConfig(n, mode="z") for n in rests)))
    rig.kill(2)  # heartbeat, SDO and PDOs stop: the patch is gone
    eventually(lambda: host.health()[2].lost, "patch 2 lost")
    lost_at = max(f.cycle for f in rig.frames)
    health = host.health()
    assert health[2].state == "lost" and health[1].state == health[3].state == "operational"
    eventually(lambda: all(sum(f.complete for f in rig.frames_of(n, lost_at)) >= 5
                           for n in (1, 3)), "patches 1 and 3 go on, complete")
    # a lost patch still gets one sample per SYNC, with no valid taxel: its force node
    # withdrew the forces and every cycle counts
    eventually(lambda: len(rig.frames_of(2, lost_at + 1)) >= 3, "patch 2's empty samples")
    assert all(not f.valid.any() and (f.reason == Reason.MISSING).all() and not f.complete
               for f in rig.frames_of(2, lost_at + 1))
    eventually(lambda: decode_force_pdos(force_pdos(rig.seen, 66), 66)[1] == 0, "withdrawal")
    mN, _ = decode_force_pdos(force_pdos(rig.seen, 66), 66)
    assert (mN == -0x8000).all()
    # it boots again: configured and back, the host was never restarted
    rig.serve(2, source(2, rests[2]))
    eventually(lambda: host.health()[2].state == "operational", "patch 2 back")
    back_at = max(f.cycle for f in rig.frames)
    eventually(lambda: len(rig.frames_of(2, back_at)) >= 3, "patch 2's forces")
    frame = rig.frames_of(2, back_at)[-1]
    assert frame.complete
    np.testing.assert_allclose(frame.force_N, expected(rests[2])[0], atol=1e-12)
    assert not host.health()[2].lost and host.health()[1].state == "operational"


def test_an_unknown_node_is_reported_and_left_alone(rig: Rig) -> None:
    rig.serve(1, source(1, press({})))
    rig.serve(9, source(9, press({})))  # a patch the config does not list, there at start
    host = rig.start(config(PatchConfig(1), sdo_timeout_ms=300))
    eventually(lambda: [u.node_id for u in rig.unknown] == [9], "node 9 reported")
    rig.serve(10, source(10, press({})))  # another one boots later
    rig.spy_bus.send(can.Message(arbitration_id=0x77E, data=b"\x00", is_extended_id=False))
    eventually(lambda: len(rig.unknown) == 3, "nodes 10 and 126 reported")
    by_id = {u.node_id: u for u in rig.unknown}
    for node_id in (9, 10):
        identity = by_id[node_id].identity
        assert identity is not None and (identity.product, identity.serial) == (1, node_id)
        assert by_id[node_id].reason == "a patch that is not in the config"
        node = rig.servers[node_id][1].nodes[0]  # untouched: not started, not remapped
        assert node.state == PRE_OPERATIONAL and int(node.store.value(0x1017)) == 1000
        assert int(node.store.value(0x1800, 2)) == 1 and len(node.tpdo.codec.layouts) == 7
    assert by_id[126].identity is None and by_id[126].reason == "did not answer SDO 0x1018"
    assert host.unknown_nodes.keys() == {9, 10, 126}
    assert set(host.health()) == {1} and host.health()[1].state == "operational"
    before = len(rig.frames_of(1))
    eventually(lambda: len(rig.frames_of(1)) > before + 3, "patch 1 goes on")


@pytest.mark.parametrize(("squatter", "patch", "message"), [
    (65, PatchConfig(1), "node-ID 65 answers on the bus but is the force node of patch 1"),
    (32, PatchConfig(1, force_cob_ids=(0x1A0, 0x1E1, 0x1E2, 0x1E3, 0x1E4, 0x1E5, 0x1E6)),
     "node 32 on the bus may transmit on 0x1A0, which the force nodes use"),
])
def test_a_node_that_collides_with_a_force_node_refuses_the_start(
        rig: Rig, squatter: int, patch: PatchConfig, message: str) -> None:
    rig.serve(1, source(1, press({})))
    rig.serve(squatter, source(squatter, press({})))
    host = HostManager(rig.bus, config(patch))
    with pytest.raises(BusError, match=message):
        host.start()
    assert not [t for t in threading.enumerate() if t.name.startswith(("sync", "dataplane",
                                                                       "patch-setup"))]
    rig.bus.send(can.Message(arbitration_id=0x123, data=b"ok", is_extended_id=False))  # open
    assert rig.servers[1][1].nodes[0].state == PRE_OPERATIONAL  # nothing was started


def test_a_faulty_taxel_is_masked_and_its_neighbours_still_decode(rig: Rig) -> None:
    loads = {3: (0.0, 0.0, 1.0), 4: (0.0, 0.0, 2.0), 5: (0.0, 0.0, 1.5)}
    good = press(loads, pillars=1)
    broken = good.copy()
    broken[4, 0] = np.inf  # pillar z of taxel 4 open: the patch sends 0xFFFF and an EMCY
    rig.serve(1, ArraySource(np.stack([good] * 20 + [broken] * 20)[:, None], (1,)))
    host = rig.start(config(PatchConfig(1, mode="z")))
    eventually(lambda: any(f.reason[4] == Reason.FAULTY for f in rig.frames), "taxel 4 masked")
    assert host.health()[1].faulty_taxels == (4,)
    masked = next(f for f in rig.frames if f.reason[4] == Reason.FAULTY)
    force, _ = expected(good)
    assert not masked.valid[4] and (masked.force_N[4] == 0).all()
    keep = np.arange(9) != 4
    assert masked.valid[keep].all() and masked.complete
    np.testing.assert_allclose(masked.force_N[keep], force[keep], atol=1e-12)
    # the pillar recovers: EMCY error reset, the taxel is unmasked
    eventually(lambda: host.health()[1].faulty_taxels == () and rig.frames[-1].valid.all(),
               "taxel 4 back")


def test_tare_rezeroes_a_patch_at_rest_and_is_refused_while_it_is_loaded(rig: Rig) -> None:
    at_rest = np.asarray(codes.resistance_to_code(np.tile(R0, (9, 1)) * 1.0003, LSB),
                         dtype=np.float64) * LSB
    rig.serve(1, source(1, at_rest))
    rig.serve(2, source(2, press({4: (0.0, 0.0, 1.0)})))
    host = rig.start(config(PatchConfig(1), PatchConfig(2)))
    eventually(lambda: rig.frames_of(1) and rig.frames_of(2), "samples of both patches")
    offset = rig.frames_of(1)[-1].force_N
    assert 0.005 < np.abs(offset).max() < 0.05  # a small reading at rest
    with pytest.raises(PatchLoadedError, match="patch 2 is loaded"):
        host.tare(2)
    host.tare(1)
    tared_at = max(f.cycle for f in rig.frames)
    eventually(lambda: rig.frames_of(1, tared_at + 1), "a sample after the tare")
    np.testing.assert_allclose(rig.frames_of(1, tared_at + 1)[-1].force_N, 0.0, atol=1e-9)
    with pytest.raises(BusError, match="node 7 is not a configured patch"):
        host.tare(7)


class ScriptedPatch:
    """A patch node whose TPDOs the test reverses, drops, duplicates or delays, by cycle."""

    def __init__(self, network: canopen.Network, resistance: np.ndarray,
                 script: dict[int, str], late_s: float) -> None:
        self.network, self.script, self.late_s = network, script, late_s
        self.node = PatchNode(1, mode="z")
        self.node.update(resistance)
        self.timers: list[threading.Timer] = []
        network.subscribe(0x80, self.on_sync)
        self.node.attach(network)

    def send(self, frames: list[tuple[int, bytes]]) -> None:
        for cob_id, data in frames:
            self.network.send_message(cob_id, data)

    def on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        cycle = data[0] - 1  # the host's cycle (< 240 here)
        frames = self.node.frames_on_sync(cycle)
        action = self.script.get(cycle % 10)
        if action == "reverse":
            frames.reverse()
        elif action == "drop":
            del frames[1]
        elif action == "duplicate":  # TPDO 1 again after TPDO 2: it ends the answer
            frames.insert(2, frames[0])
        elif action == "late":
            timer = threading.Timer(self.late_s, self.send, [frames[2:]])
            self.timers.append(timer)
            timer.start()
            frames = frames[:2]
        self.send(frames)

    def close(self) -> None:
        for timer in self.timers:
            timer.join()
        self.node.detach()


def test_lost_duplicated_reordered_and_late_frames_end_to_end(rig: Rig) -> None:
    resistance = press({k: (0.0, 0.0, 0.5 + k / 4) for k in range(9)}, pillars=1)
    net = rig.network()
    # SYNC every 100 ms, window 40 ms, the late PDO 70 ms after SYNC: wide margins both ways
    script = {2: "reverse", 4: "drop", 6: "duplicate", 8: "late"}
    patch = ScriptedPatch(net, resistance, script, late_s=0.07)
    try:
        host = rig.start(config(PatchConfig(1, mode="z"), sync_period_ms=100.0,
                                sync_window_ms=40.0))
        eventually(lambda: any(f.cycle >= 19 for f in rig.frames), "two rounds of the script")
        stats = host.stats()
    finally:
        rig.host = None
        host.stop()
        patch.close()
        net.disconnect()
    force, _ = expected(resistance)
    # An answer is a unit sent in order: reversed, its first two frames are the tail of
    # an earlier answer and only the first TPDO counts; a lost or repeated PDO ends it.
    rows = {"reverse": [3, 4, 5, 6, 7, 8], "drop": [3, 4, 5, 6, 7, 8],
            "duplicate": [0, 1, 2, 6, 7, 8], "late": [6, 7, 8]}
    frames = [f for f in rig.frames if f.cycle >= 1]
    checked = set()
    for frame in frames:
        action = script.get(frame.cycle % 10, "normal")
        missing = np.zeros(9, bool)
        missing[rows.get(action, [])] = True
        assert frame.complete == (action == "normal"), (frame.cycle, action)
        assert (frame.reason[missing] == Reason.MISSING).all(), (frame.cycle, action)
        assert frame.valid[~missing].all()
        np.testing.assert_allclose(frame.force_N[~missing], force[~missing], atol=1e-12)
        assert (frame.force_N[missing] == 0).all()
        checked.add(action)
    assert checked == {"normal", "reverse", "drop", "duplicate", "late"}
    assert stats["duplicate_frames"] >= 1 and stats["late_frames"] >= 1
    assert [f.cycle for f in frames] == sorted(f.cycle for f in frames)  # one per cycle
    assert len({f.cycle for f in frames}) == len(frames)


def test_callbacks_and_iterators_see_the_same_frames_and_a_slow_one_drops(rig: Rig) -> None:
    rig.serve(1, source(1, press({1: (0.0, 0.0, 1.0)}, pillars=1)))
    host = rig.start(replace(config(PatchConfig(1, mode="z")), queue_size=4))
    boom: list[int] = []

    def failing(frame: ForceFrame) -> None:
        boom.append(frame.cycle)
        raise RuntimeError("a consumer bug")

    host.on_forces(failing)
    fast = host.frames(timeout=WAIT_S, maxsize=1000)
    slow = host.frames(timeout=WAIT_S)  # never read until the end: holds 4, drops the rest
    first = [next(fast) for _ in range(12)]
    assert [f.cycle for f in first] == list(range(first[0].cycle, first[0].cycle + 12))
    assert host.api_dropped > 0 and host.callback_errors == len(boom) > 0
    kept = [next(slow) for _ in range(4)]
    assert [f.cycle for f in kept] == sorted(f.cycle for f in kept)
    host.remove_callback(failing)
    host.stop()
    assert list(host.frames(timeout=0.1)) == []  # a stopped host ends iteration


def test_a_patch_decodes_with_the_model_file_its_config_names(
        rig: Rig, tmp_path_factory: pytest.TempPathFactory) -> None:
    frame = Simulator(load_scene("paper")).run(300)
    model = create_decoder("deconv").fit(frame.resistance_ohm[:, 0], frame.force_N[:, 0])
    path = tmp_path_factory.mktemp("models") / "deconv-z.msgpack"
    model.save(path)
    pressed = press({4: (0.0, 0.0, 2.0), 5: (0.0, 0.0, 1.0)}, pillars=1)
    rig.serve(1, source(1, pressed))
    rig.serve(2, source(2, pressed))
    rig.start(config(PatchConfig(1, mode="z"), PatchConfig(2, mode="z", model=path)))
    eventually(lambda: rig.frames_of(1) and rig.frames_of(2), "samples of both patches")
    analytic, by_model = rig.frames_of(1)[-1], rig.frames_of(2)[-1]
    np.testing.assert_allclose(analytic.force_N, expected(pressed)[0], atol=1e-12)
    np.testing.assert_allclose(by_model.force_N, model.decode(pressed[None]).force_N[0],
                               atol=1e-12)
    assert not np.allclose(by_model.force_N, analytic.force_N)  # it is the model's answer


def test_drift_tracking_zeroes_the_rest_and_keeps_a_steady_contact(rig: Rig) -> None:
    drifted = press({4: (0.0, 0.0, 1.0)}, pillars=1)
    rest = np.arange(9) != 4
    drifted[rest] = np.rint(drifted[rest] * 1.0003 / LSB) * LSB  # the rest drifted +0.03 %
    rig.serve(1, source(1, drifted))
    host = rig.start(config(PatchConfig(1, mode="z"), drift=DriftConfig(0.05, 0.1)))
    eventually(lambda: rig.frames_of(1), "a sample")
    first = rig.frames_of(1)[0].force_N
    assert np.abs(first[rest]).max() > 0.005  # the drift reads as a force at first
    eventually(lambda: np.abs(rig.frames_of(1)[-1].force_N[rest]).max() < 1e-4,
               "the rest tracked to zero")
    np.testing.assert_allclose(rig.frames_of(1)[-1].force_N[4], first[4], atol=1e-12)
    assert host.health()[1].state == "operational"
