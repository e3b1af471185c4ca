"""The host manager's parts on their own: heartbeat consumer, SYNC producer and follower,
baseline, set-up (over SDO, and planned from the config for a listen-only host)."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterator

import can
import canopen
import numpy as np
import pytest

from canbus.device.nmt_slave import PRE_OPERATIONAL
from canbus.device.patch_node import PatchNode, z_only_mapping
from canbus.master.baseline import Baseline, PatchLoadedError
from canbus.master.hostconfig import PatchConfig
from canbus.master.liveness import HeartbeatMonitor
from canbus.master.patch_setup import (
    PatchInfo,
    configured_info,
    patch_info,
    plan_setup,
    read_patch_info,
    setup_patch,
    tpdo_layouts,
    warn_if_unlike_config,
)
from canbus.master.sync_producer import SyncFollower, SyncProducer, sync_counter
from canbus.od import load_od
from decoder.analytic import AnalyticDecoder
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.tripod import resistance_from_force


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class Events:
    def __init__(self) -> None:
        self.log: list[tuple[str, int, int | None]] = []

    def boot(self, node: int) -> None:
        self.log.append(("boot", node, None))

    def lost(self, node: int) -> None:
        self.log.append(("lost", node, None))

    def back(self, node: int, state: int) -> None:
        self.log.append(("return", node, state))

    def change(self, node: int, state: int) -> None:
        self.log.append(("change", node, state))


def _monitor(period_ms: int = 100, *,
             changes: bool = False) -> tuple[HeartbeatMonitor, Clock, Events]:
    clock, events = Clock(), Events()
    monitor = HeartbeatMonitor(canopen.Network(), period_ms, on_boot=events.boot,
                               on_lost=events.lost, on_return=events.back,
                               on_change=events.change if changes else None, clock=clock)
    monitor.watch(3)
    return monitor, clock, events


@pytest.mark.parametrize("phase", [0.0, 0.01, 0.02, 0.03, 0.049])
def test_a_silent_patch_is_lost_within_two_heartbeat_periods(phase: float) -> None:
    monitor, clock, events = _monitor(100)
    monitor.on_heartbeat(0x703, bytearray(b"\x05"), 0.0)
    assert events.log == [("return", 3, 5)], events.log  # first heard: operational
    last = clock.now
    # The monitor's thread checks every quarter period; its phase against the last
    # heartbeat is arbitrary.
    clock.now += phase
    while not monitor.check():
        assert not monitor.check()  # reported once
        clock.now += 0.025
    delay = clock.now - last
    assert 0.15 < delay <= 0.2  # after 1.5 periods of silence, within 2
    assert events.log[-1] == ("lost", 3, None) and not monitor.alive(3)
    clock.now += 1.0
    assert monitor.check() == []  # not reported again
    monitor.on_heartbeat(0x703, bytearray(b"\x7f"), 0.0)
    assert events.log[-2:] == [("lost", 3, None), ("return", 3, 0x7F)] and monitor.alive(3)


def test_heartbeats_keep_a_patch_alive_and_boot_ups_are_reported() -> None:
    monitor, clock, events = _monitor(100)
    for _ in range(20):
        monitor.on_heartbeat(0x703, bytearray(b"\x05"), 0.0)
        clock.now += 0.14  # a late heartbeat, still inside 1.5 periods
        assert monitor.check() == []
    monitor.on_heartbeat(0x703, bytearray(b"\x00"), 0.0)
    monitor.on_heartbeat(0x704, bytearray(b"\x00"), 0.0)  # not watched
    monitor.on_heartbeat(0x703, bytearray(b"\x05\x00"), 0.0)  # not a heartbeat
    assert events.log == [("return", 3, 5), ("boot", 3, None)]
    assert monitor.state(3) == 0 and monitor.last_heartbeat(3) is not None


def test_silence_is_judged_only_once_our_heartbeat_period_is_set() -> None:
    monitor, clock, events = _monitor(100)
    monitor.watch(4, judged=False)  # heard before the host wrote its 0x1017
    monitor.on_heartbeat(0x704, bytearray(b"\x7f"), 0.0)
    clock.now += 0.9  # the node's own default period (1000 ms): not lost
    assert monitor.check() == [] and monitor.alive(4)
    monitor.judge(4, True)  # set-up wrote 0x1017 = 100 ms
    clock.now += 0.14
    assert monitor.check() == []
    clock.now += 0.05
    assert monitor.check() == [4] and events.log[-1] == ("lost", 4, None)


def test_a_patch_never_heard_is_not_lost() -> None:
    monitor, clock, events = _monitor(100)
    clock.now += 10.0
    assert monitor.check() == [] and events.log == []


def test_entering_and_leaving_operational_is_reported_as_a_change() -> None:
    monitor, _, events = _monitor(100, changes=True)
    for state in (0x00, 0x7F, 0x7F, 0x05, 0x05, 0x04, 0x7F, 0x05):
        monitor.on_heartbeat(0x703, bytearray([state]), 0.0)
    # boot-up, then pre-operational (no change: not operational either), then in and out
    assert events.log == [("boot", 3, None), ("change", 3, 5), ("change", 3, 4),
                          ("change", 3, 5)]


def test_an_expected_node_is_lost_unless_its_heartbeat_comes() -> None:
    monitor, clock, events = _monitor(100)
    monitor.expect(3)  # never heard, but a master has just started it
    assert monitor.alive(3)
    clock.now += 0.14
    assert monitor.check() == []
    monitor.on_heartbeat(0x703, bytearray(b"\x05"), 0.0)  # it answers: alive, no return
    clock.now += 0.14
    assert monitor.check() == [] and events.log == []
    clock.now += 0.02
    assert monitor.check() == [3]
    monitor.expect(3)  # started again, silent again
    clock.now += 0.151
    assert monitor.check() == [3] and events.log == [("lost", 3, None)] * 2
    monitor.expect(4)  # not watched: nothing
    assert not monitor.alive(4)


@pytest.fixture
def pair(request: pytest.FixtureRequest) -> Iterator[tuple[can.BusABC, can.BusABC]]:
    a = can.Bus(interface="virtual", channel=request.node.name)
    b = can.Bus(interface="virtual", channel=request.node.name)
    yield a, b
    a.shutdown()
    b.shutdown()


def test_sync_goes_out_after_the_data_plane_knows_its_cycle(
        pair: tuple[can.BusABC, can.BusABC]) -> None:
    host, patch = pair
    told: list[tuple[int, int, float]] = []
    producer = SyncProducer(host, 0.005, on_sync=lambda *a: told.append(a))
    for _ in range(3):
        producer.send_one()
    frames = [patch.recv(1.0) for _ in range(3)]
    assert [c for c, _, _ in told] == [1, 2, 3]
    assert [bytes(m.data) for m in frames if m] == [b"\x02", b"\x03", b"\x04"]
    for (_, counter, t), msg in zip(told, frames, strict=True):
        assert msg is not None and msg.arbitration_id == 0x80 and msg.data[0] == counter
        assert t <= msg.timestamp  # a PDO answering this SYNC is stamped after t
    quiet = SyncProducer(host, 0.005, on_sync=lambda *a: told.append(a), counter=False)
    quiet.send_one()
    msg = patch.recv(1.0)
    assert msg is not None and bytes(msg.data) == b"" and told[-1][:2] == (1, 0)


def test_sync_counter_runs_1_to_240() -> None:
    assert [sync_counter(c) for c in (1, 238, 239, 240, 241, 480)] == [2, 239, 240, 1, 2, 1]


def test_the_sync_thread_runs_and_stops(pair: tuple[can.BusABC, can.BusABC]) -> None:
    host, patch = pair
    seen = threading.Semaphore(0)
    producer = SyncProducer(host, 0.002, on_sync=lambda *a: seen.release())
    producer.start()
    try:
        for _ in range(10):
            assert seen.acquire(timeout=5.0)
    finally:
        producer.stop()
    cycles = producer.cycle
    assert cycles >= 10 and not producer.send_errors
    counted = 0
    while patch.recv(0.0) is not None:
        counted += 1
    assert counted == cycles  # one frame per cycle, none after stop()


def test_a_late_sync_restarts_the_schedule_instead_of_a_burst(
        pair: tuple[can.BusABC, can.BusABC]) -> None:
    """Cycle 3 ends 0.8 period late: the next SYNC comes a period after it, not at once."""
    host, _ = pair
    period = 0.02
    sent: list[float] = []
    done = threading.Semaphore(0)

    def on_sync(cycle: int, counter: int, timestamp: float) -> None:
        sent.append(time.monotonic())
        if cycle == 3:
            time.sleep(0.8 * period)
        if cycle == 6:
            done.release()

    producer = SyncProducer(host, period, on_sync=on_sync)
    producer.start()
    try:
        assert done.acquire(timeout=10.0)
    finally:
        producer.stop()
    gaps = np.diff(sent[:6])
    assert producer.overruns >= 1
    assert gaps.min() >= 0.45 * period, gaps  # with a burst, SYNC 4 came 0.2 period after 3
    assert gaps[2] >= 1.5 * period  # 0.8 period late plus a full period

def test_a_follower_opens_a_cycle_for_every_sync_received(
        pair: tuple[can.BusABC, can.BusABC], caplog: pytest.LogCaptureFixture) -> None:
    told: list[tuple[int, int, float]] = []
    follower = SyncFollower(lambda *a: told.append(a))
    frames = [
        can.Message(timestamp=1.0, arbitration_id=0x80, data=b"\x11", is_extended_id=False),
        can.Message(timestamp=2.0, arbitration_id=0x80, data=b"", is_extended_id=False),
        can.Message(timestamp=3.0, arbitration_id=0x80, data=b"\x01\x02",
                    is_extended_id=False),  # not a SYNC (CiA 301: 0 or 1 byte)
        can.Message(timestamp=4.0, arbitration_id=0x80, data=b"\x01"),  # 29-bit identifier
        can.Message(timestamp=5.0, arbitration_id=0x80, is_remote_frame=True,
                    is_extended_id=False),
        can.Message(timestamp=6.0, arbitration_id=0x81, data=b"\x01", is_extended_id=False),
        can.Message(timestamp=7.0, arbitration_id=0x80, data=b"\xf0", is_extended_id=False),
    ]
    for msg in frames:
        follower.on_message_received(msg)
    assert told == [(1, 0x11, 1.0), (2, 0, 2.0), (3, 0xF0, 7.0)] and follower.cycle == 3

    def broken(*_: object) -> None:
        raise RuntimeError("boom")

    failing = SyncFollower(broken)  # logged, never raised into the notifier's thread
    with caplog.at_level(logging.ERROR):
        failing.on_message_received(frames[0])
    assert failing.cycle == 1 and "SYNC cycle 1 failed" in caplog.text
    # and on a bus, through a notifier, with the bus's timestamps
    host, master = pair
    follower = SyncFollower(lambda *a: told.append(a))
    notifier = can.Notifier(host, [follower], timeout=0.05)
    try:
        master.send(can.Message(arbitration_id=0x80, data=b"\x05", is_extended_id=False))
        deadline = threading.Event()
        for _ in range(200):
            if follower.cycle:
                break
            deadline.wait(0.005)
    finally:
        notifier.stop()
    assert follower.cycle == 1 and told[-1][:2] == (1, 5) and told[-1][2] > 1e9


R0 = DEFAULT_CONSTANTS.nominal_resistance_ohm  # (3,)


def _press(fz: float, taxel: int = 4) -> np.ndarray:
    force = np.zeros((9, 3))
    force[taxel, 2] = fz
    return resistance_from_force(force, DEFAULT_CONSTANTS)


def test_tare_is_refused_while_loaded_and_rezeroes_at_rest() -> None:
    decoder = AnalyticDecoder()
    offset = np.tile(R0, (9, 1)) * 1.0003  # at rest, but 0.03 % above R0: ~36 mN
    baseline = Baseline(np.tile(R0, (9, 1)), np.tile(R0, (9, 1)), loaded_N=0.05)
    assert np.array_equal(baseline.scale, np.ones((9, 3)))
    before = decoder.decode(offset[None] * baseline.scale)
    assert 0.005 < np.abs(before.force_N[0, :, 2]).min() <= np.abs(before.force_N).max() < 0.05
    pressed = _press(0.5) * 1.0003
    loaded = decoder.decode(pressed[None] * baseline.scale)
    refused = r"patch 7 is loaded \(taxel 4 0.4\d+ N > 0.05 N\): tare refused"
    with pytest.raises(PatchLoadedError, match=refused):
        baseline.tare(pressed, loaded.force_N[0], loaded.valid[0], node_id=7)
    with pytest.raises(PatchLoadedError, match="no complete sample"):
        baseline.tare(None, None, None, node_id=7)
    scale = baseline.tare(offset, before.force_N[0], before.valid[0], node_id=7)
    after = decoder.decode(offset[None] * scale)
    np.testing.assert_allclose(after.force_N, 0.0, atol=1e-9)
    again = decoder.decode(pressed[None] * scale)  # the press reads as before the offset
    np.testing.assert_allclose(again.force_N[0, 4], [0.0, 0.0, 0.5], atol=1e-6)


def test_drift_tracking_follows_free_taxels_and_freezes_on_contact() -> None:
    decoder = AnalyticDecoder()
    published: list[np.ndarray] = []
    baseline = Baseline(np.tile(R0, (9, 1)), np.tile(R0, (9, 1)), loaded_N=0.05,
                        time_constant_s=1.0, contact_N=0.1, on_scale=published.append)
    free = np.arange(9) != 4
    for step in range(1, 2001):  # 20 s at 100 Hz: the rest of untouched taxels drifts 0.1 %
        raw = _press(1.0)  # a steady 1 N press on taxel 4
        raw[free] *= 1.0 + 1e-3 * min(1.0, step / 1000)
        out = decoder.decode(raw[None] * baseline.scale)
        baseline.track(raw, out.force_N[0], out.valid[0], 0.01)
    np.testing.assert_allclose(out.force_N[0, free], 0.0, atol=1e-4)  # drift tracked away
    np.testing.assert_allclose(out.force_N[0, 4], [0.0, 0.0, 1.0], atol=1e-9)  # never fades
    np.testing.assert_array_equal(baseline.baseline[4], R0)
    assert len(published) == 2001 and published[-1] is baseline.scale


def test_without_a_time_constant_tracking_changes_nothing() -> None:
    baseline = Baseline(R0, np.tile(R0, (9, 1)), loaded_N=0.05)
    scale = baseline.track(np.tile(R0, (9, 1)) * 1.01, np.zeros((9, 3)), np.ones(9, bool), 1.0)
    assert np.array_equal(scale, np.ones((9, 3)))


@pytest.fixture
def patch_net(request: pytest.FixtureRequest) -> Iterator[tuple[PatchNode, canopen.RemoteNode]]:
    device, master = canopen.Network(), canopen.Network()
    for net in (device, master):
        net.NOTIFIER_CYCLE = 0.05
        net.connect(interface="virtual", channel=request.node.name)
    constants = SensorConstants(resistivity_ohm_m=0.5, taxel_pitch_m=0.02)
    node = PatchNode(9, mode="z", constants=constants)
    node.attach(device)
    remote = master.add_node(canopen.RemoteNode(9, load_od("skin-patch", 9)))
    remote.sdo.RESPONSE_TIMEOUT = 2.0
    yield node, remote
    node.detach()
    master.disconnect()
    device.disconnect()


def test_setup_reads_the_constants_and_maps_the_decoders_mode(
        patch_net: tuple[PatchNode, canopen.RemoteNode]) -> None:
    node, remote = patch_net
    info = read_patch_info(remote.sdo, 9)
    assert info.constants == node.constants  # scaled counts read back as the same SI values
    np.testing.assert_allclose(info.r0_ohm, np.tile(node.constants.nominal_resistance_ohm,
                                                    (9, 1)), rtol=0, atol=0.5e-3)
    # a z-only node, mapped for 3 axes: 27 codes in TPDO 1..7, every SYNC, heartbeat 250 ms
    setup = setup_patch(remote, "xyz", heartbeat_ms=250)
    assert [x.cob_id for x in setup.layouts] == [0x189, 0x289, 0x389, 0x489, 0x209, 0x309, 0x409]
    assert node.tpdo.codec.layouts == setup.layouts
    assert [int(node.store.value(0x1800 + n, 2)) for n in range(7)] == [1] * 7
    assert int(node.store.value(0x1017)) == 250 and node.heartbeat.period_ms == 250
    assert node.state == PRE_OPERATIONAL
    # and back to z: 3 TPDOs, one grid row each, TPDO 4..7 invalid
    setup = setup_patch(remote, "z", heartbeat_ms=100)
    assert setup.layouts == tpdo_layouts(9, "z") == node.tpdo.codec.layouts
    assert [[e.to_raw() for e in x.entries] for x in setup.layouts] == z_only_mapping()
    assert all(int(node.store.value(0x1800 + n, 1)) & 0x8000_0000 for n in range(3, 7))
    values = np.arange(9, dtype=np.float64)[None, :] + 1000
    assert np.array_equal(setup.codec.unpack(node.tpdo.codec.pack(values)), values)


def _same_info(a: PatchInfo, b: PatchInfo) -> bool:
    return (a.node_id, a.lsb_ohm, a.constants) == (b.node_id, b.lsb_ohm, b.constants) and \
        np.array_equal(a.r0_ohm, b.r0_ohm)


def test_a_listen_only_host_plans_the_setup_the_host_writes_and_reads(
        patch_net: tuple[PatchNode, canopen.RemoteNode], caplog: pytest.LogCaptureFixture) -> None:
    node, remote = patch_net
    read = read_patch_info(remote.sdo, 9)
    # what the patch reports, computed from its constants: every value through its count
    assert _same_info(patch_info(9, node.constants), read)
    assert _same_info(configured_info(PatchConfig(9, constants=node.constants)), read)
    assert _same_info(patch_info(9), configured_info(PatchConfig(9)))  # DEFAULT_CONSTANTS
    assert patch_info(9).constants == DEFAULT_CONSTANTS
    custom = configured_info(PatchConfig(9, r0_ohm=(1001.0, 1415.0, 1414.0)))
    assert np.array_equal(custom.r0_ohm, np.tile([1001.0, 1415.0, 1414.0], (9, 1)))
    # the mapping planned for each mode is the one setup_patch writes, and its codec
    for mode in ("xyz", "z"):
        written = setup_patch(remote, mode, heartbeat_ms=100)
        planned = plan_setup(9, remote.object_dictionary, mode, read)
        assert planned.layouts == written.layouts == node.tpdo.codec.layouts
        assert planned.codec.variables == written.codec.variables
        assert np.array_equal(planned.codec.cob_ids, written.codec.cob_ids)
        assert (planned.mode, planned.pillars) == (written.mode, written.pillars)
    # a normal host warns when the patch disagrees with constants given for listen-only
    with caplog.at_level(logging.WARNING, logger="canbus.master.host"):
        warn_if_unlike_config(PatchConfig(9, constants=node.constants), read)
        assert not caplog.records
        warn_if_unlike_config(PatchConfig(9, constants=DEFAULT_CONSTANTS,
                                           r0_ohm=(1001.0, 1415.0, 1414.0)), read)
    messages = [r.getMessage() for r in caplog.records]
    assert len(messages) == 2 and messages[0].startswith("patch 9 reports constants ")
    assert messages[1].startswith("patch 9 reports another R0 than the config's r0_ohm")


def test_the_emcy_log_of_a_long_running_host_stays_bounded() -> None:
    from canbus.master.emcy import EMCY_LOG_KEPT
    from canbus.master.host import HostManager
    from canbus.master.hostconfig import HostConfig, PatchConfig

    with can.Bus(interface="virtual", channel="emcy-log-bound") as bus:
        host = HostManager(bus, HostConfig(patches=(PatchConfig(1),)).check())
        consumer = host.patches[1].node.emcy  # the canopen EmcyConsumer of patch 1
        for k in range(5 * EMCY_LOG_KEPT):  # taxel 4 flapping: fault, reset, fault, ...
            code = 0x5000 if k % 2 == 0 else 0x0000
            consumer.on_emcy(0x81, code.to_bytes(2, "little") + bytes([0x81 if code else 0,
                                                                       4, 1, 0, 0, 0]), k)
        assert len(consumer.log) <= 2 * EMCY_LOG_KEPT + 1
        assert consumer.log[-1].timestamp == 5 * EMCY_LOG_KEPT - 1  # the newest are kept
        assert host.health()[1].faulty_taxels == ()  # the last one was the reset
