"""Set-ups that fail and stops that must be prompt, on a virtual bus (one process): a rogue
R0, a node that is not a patch, garbled SDO answers, a scan or an SDO transfer that would
take its time, a foreign node at a force node's ID, an EMCY flood."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterator

import can
import pytest
from canopen.emcy import EmcyConsumer

from canbus.master.cobids import predefined_tpdo_cob_ids
from canbus.master.dataplane import ForceFrame
from canbus.master.emcy import EMCY_LOG_KEPT
from canbus.master.hostconfig import PatchConfig
from canbus.patch_constants import scale_of
from decoder.reasons import Reason
from tests.canbus.faults import rss_bytes
from tests.support.rigs.host import Rig, config, eventually, press, source

RECOVERY_CYCLES = 300  # 3 s of SYNC at 100 Hz
WAIT_S = 20.0
LONGEST_MS = 600_000  # the longest scan and SDO time-out a config may ask for: 10 minutes
NOMINAL, IDENTITY = 0x2002, 0x1018


@pytest.fixture
def rig(request: pytest.FixtureRequest) -> Iterator[Rig]:
    r = Rig(f"setup-{request.node.name}")
    yield r
    r.close()


def _cycles(rig: Rig) -> int:
    assert rig.host is not None
    return rig.host.stats()["sync_cycles"]


def test_a_rogue_r0_is_a_setup_failure_with_its_reason_retried_until_it_is_fixed(
        rig: Rig, caplog: pytest.LogCaptureFixture) -> None:
    """R0 is an UNSIGNED32 count of mOhm on the wire (eds/skin-patch.eds): NaN and negative
    values cannot be sent; 0 is one outside the range a real patch has."""
    server = rig.serve(1, source(1, press({})))
    node = server.nodes[0]
    good = float(node.store.value(NOMINAL, 4))
    node.store.store(NOMINAL, 4, 0)  # taxel 1, pillar z
    caplog.set_level(logging.WARNING, logger="canbus.master.setup_jobs")
    host = rig.start(config(PatchConfig(1)))
    eventually(lambda: host.health()[1].setup_failures >= 2, "set-up retried")
    health = host.health()[1]
    assert health.state == "configuring" and health.error is not None
    assert "0x2002 sub 4 (R0 of taxel 1, pillar z) = 0 mOhm" in health.error
    assert "outside 100..1000000000 mOhm" in health.error
    lines = [r.getMessage() for r in caplog.records if r.name == "canbus.master.setup_jobs"]
    assert lines and "0x2002 sub 4" in lines[0] and "again in" in lines[0]
    node.store.store(NOMINAL, 4, good)
    at = _cycles(rig)
    assert host.wait_operational(timeout=WAIT_S)
    assert _cycles(rig) - at <= RECOVERY_CYCLES
    assert host.health()[1].error is None


GARBAGE = [(0x2001, 0, "resistance LSB", "uOhm"), (0x2002, 4, "R0 of taxel 1, pillar z", "mOhm"),
           (0x2003, 1, "Young's modulus", "Pa"), (0x2003, 2, "resistivity", "uOhm m"),
           (0x2003, 3, "pillar length", "um"), (0x2003, 4, "pillar cross-section", "um2"),
           (0x2003, 5, "max strain", "ppm"), (0x2003, 6, "full-scale force", "mN"),
           (0x2003, 7, "taxel pitch", "um")]
"""Every constant a patch reports: (index, sub-index, what the reason calls it, unit)."""


@pytest.mark.parametrize("count", [0xFFFF_FFFF, 0], ids=["all-ones", "zero"])
@pytest.mark.parametrize(("index", "subindex", "name", "unit"), GARBAGE,
                         ids=[f"{i:04X}sub{s}" for i, s, _, _ in GARBAGE])
def test_a_patch_reporting_a_constant_no_real_patch_has_is_refused_and_publishes_no_force(
        rig: Rig, index: int, subindex: int, name: str, unit: str, count: int) -> None:
    """Issue 33: a patch whose firmware reports its Young's modulus as 0xFFFFFFFF (4.29 GPa)
    was configured and published forces with their valid bits set."""
    server = rig.serve(1, source(1, press({4: (0.0, 0.0, 1.0)})))  # a light press
    server.nodes[0].store.store(index, subindex, count)  # the firmware's own value
    host = rig.start(config(PatchConfig(1)))
    eventually(lambda: host.health()[1].setup_failures >= 2, "set-up retried")
    health = host.health()[1]
    assert health.state == "configuring" and health.error is not None
    where = f"0x{index:04X}" if index == 0x2001 else f"0x{index:04X} sub {subindex}"
    low, high = scale_of(index, subindex).count_range  # type: ignore[union-attr]
    assert f"patch 1 reports {where} ({name}) = {count} {unit}" in health.error
    assert f"outside {low}..{high} {unit}" in health.error
    assert health.error.count(" = ") == 1  # one reason, one object
    assert not any(f.valid.any() for f in list(rig.frames) if f.patch == 1)
    valid_pdo = predefined_tpdo_cob_ids(65)[6]  # TPDO 7: 0x2005, the valid bits
    assert not any(int.from_bytes(m.data[6:8], "little") & 0x1FF for m in list(rig.seen)
                   if m.arbitration_id == valid_pdo)


def test_a_node_that_is_not_a_patch_fails_for_good_until_it_boots_again(rig: Rig) -> None:
    server = rig.serve(1, source(1, press({})))
    server.nodes[0].store.store(IDENTITY, 2, 7)  # product 7: not a patch
    host = rig.start(config(PatchConfig(1)))
    eventually(lambda: host.health()[1].state == "failed", "refused three times")
    health = host.health()[1]
    assert health.error is not None and "is not a patch" in health.error
    assert "product 7" in health.error and health.setup_failures == 3
    # Someone puts a patch there (the node resets with its defaults): configured again.
    rig.spy_bus.send(can.Message(arbitration_id=0x000, data=b"\x81\x01", is_extended_id=False))
    assert host.wait_operational(timeout=WAIT_S)
    assert [state for _, state, _ in host.health()[1].history][-3:] == \
        ["failed", "configuring", "operational"]


def test_garbled_sdo_answers_during_a_setup_fail_it_and_it_is_retried(rig: Rig) -> None:
    rig.serve(1, source(1, press({})))
    stop = threading.Event()
    garbled = 0

    def flood() -> None:
        nonlocal garbled
        with can.Bus(interface="virtual", channel=rig.channel) as bus:
            while not stop.is_set():
                bus.send(can.Message(arbitration_id=0x581, data=bytes([0x43, 0x42, 0x80,
                                                                         0x40, 1, 2, 3, 4]),
                                     is_extended_id=False))
                garbled += 1
                time.sleep(0.0005)  # pacing: about 2,000 garbled answers a second

    flooding = threading.Thread(target=flood)
    flooding.start()
    try:
        host = rig.start(config(PatchConfig(1), sdo_timeout_ms=300))
        eventually(lambda: host.health()[1].setup_failures >= 1, "a failed set-up")
    finally:
        stop.set()
        flooding.join()
    at = _cycles(rig)
    assert host.wait_operational(timeout=WAIT_S)
    assert _cycles(rig) - at <= RECOVERY_CYCLES
    history = [state for _, state, _ in host.health()[1].history]
    assert "failed" not in history and history[-1] == "operational" and garbled > 0


def test_stop_ends_a_long_scan_at_once(rig: Rig) -> None:
    """start() in a 10-minute scan ends with stop(), long before the scan would: the wait
    for it has a deadline of seconds."""
    rig.serve(1, source(1, press({})))
    started = threading.Event()
    from canbus.master.host import HostManager

    host = HostManager(rig.bus, config(PatchConfig(1), scan_ms=LONGEST_MS))

    def run() -> None:
        started.set()
        host.start()

    starting = threading.Thread(target=run)
    starting.start()
    started.wait()
    eventually(lambda: host.running, "the start under way")
    began = time.monotonic()
    host.stop()
    eventually(lambda: not starting.is_alive(), "start() ended, 10 minutes before its scan")
    print(f"\nstop() in a 10-minute scan: start and stop ended after "
          f"{time.monotonic() - began:.3f} s")
    assert not host.running


def test_stop_cuts_a_setup_waiting_on_sdo_short(rig: Rig) -> None:
    """A node that answers the scan and beats, then never answers SDO: its set-up waits
    on a 10-minute time-out per request, which stop() does not wait out (the wait for the
    start to end has a deadline of seconds)."""
    net = rig.network()

    def on_request(can_id: int, data: bytearray, timestamp: float) -> None:
        if data[1:3] == b"\x00\x10":  # the scan's upload of 0x1000: answered
            net.send_message(0x581, bytes([0x43, 0x00, 0x10, 0x00, 0x91, 0x01, 0x0F, 0x00]))

    net.subscribe(0x601, on_request)
    net.send_periodic(0x701, b"\x7f", 0.1)
    from canbus.master.host import HostManager

    host = HostManager(rig.bus, config(PatchConfig(1), sdo_timeout_ms=LONGEST_MS))
    starting = threading.Thread(target=host.start)
    starting.start()
    eventually(lambda: host.health()[1].state == "configuring", "the set-up under way")
    began = time.monotonic()
    host.stop()
    eventually(lambda: not starting.is_alive(),
               "start() ended, 10 minutes before its SDO time-out")
    print(f"\nstop() in a set-up waiting on a 10-minute SDO time-out: ended after "
          f"{time.monotonic() - began:.3f} s")
    assert not host.running
    net.disconnect()
    rig.servers.clear()


def test_a_foreign_node_at_a_force_node_id_is_reported_and_the_force_node_goes_on(
        rig: Rig, caplog: pytest.LogCaptureFixture) -> None:
    rig.serve(1, source(1, press({4: (0.0, 0.0, 1.0)})))
    host = rig.start(config(PatchConfig(1)))
    assert host.wait_operational(timeout=WAIT_S)
    caplog.set_level(logging.WARNING, logger="canbus.master.active")
    for state in (0x00, 0x05, 0x05):  # a node at 65 boots and beats
        rig.spy_bus.send(can.Message(arbitration_id=0x741, data=bytes([state]),
                                     is_extended_id=False))
    eventually(lambda: host.health()[1].force_conflict is not None, "the conflict reported")
    conflict = host.health()[1].force_conflict
    assert conflict is not None and "force node 65" in conflict and "0x741" in conflict
    lines = [r.getMessage() for r in caplog.records if r.name == "canbus.master.active"]
    assert len(lines) == 1 and "another node transmits at the ID of patch 1's force node" \
        in lines[0]
    after = len(rig.frames)
    last_tpdo = predefined_tpdo_cob_ids(65)[-1]
    seen = len([m for m in rig.seen if m.arbitration_id == last_tpdo])
    eventually(lambda: len([f for f in rig.frames[after:] if f.published]) >= 20,
               "force frames still published")
    eventually(lambda: len([m for m in list(rig.seen) if m.arbitration_id == last_tpdo])
               >= seen + 20, "force TPDOs still on the bus")
    assert host.health()[1].state == "operational"


def test_an_emcy_flood_never_reset_keeps_memory_flat_and_the_patch_decoded(rig: Rig) -> None:
    rig.serve(1, source(1, press({4: (0.0, 0.0, 1.0)})))
    host = rig.start(config(PatchConfig(1)))
    assert host.wait_operational(timeout=WAIT_S)
    flood = 50_000
    emcy = can.Message(arbitration_id=0x81, data=bytes([0x00, 0x50, 0x81, 4, 1, 0, 0, 0]),
                       is_extended_id=False)
    consumer = host.patch(1).node.emcy
    rig.spy.listeners.clear()  # the rig's spy keeps every frame: not during the flood
    before = rss_bytes()
    with can.Bus(interface="virtual", channel=rig.channel) as flooder:
        for sent in range(0, flood, 500):  # in bursts: the bus's own queue stays short
            for _ in range(500):
                flooder.send(emcy)
            eventually(lambda: consumer.received >= sent + 500, "the burst consumed",  # noqa: B023
                       timeout=120.0)
    grown = rss_bytes() - before
    assert len(consumer.log) <= 2 * EMCY_LOG_KEPT and len(consumer.active) <= 2 * EMCY_LOG_KEPT
    # canopen's own consumer, fed the same EMCYs here, is what grows without bound.
    reference = EmcyConsumer()
    ref_before = rss_bytes()
    for k in range(flood):
        reference.on_emcy(0x81, emcy.data, float(k))
    ref_grown = rss_bytes() - ref_before
    assert len(reference.active) == flood
    print(f"RSS over {flood} EMCYs: host {grown / 1024:.0f} KiB, canopen's consumer "
          f"{ref_grown / 1024:.0f} KiB")
    assert grown < max(2 << 20, ref_grown // 4), (grown, ref_grown)
    # The patch goes on: taxel 4 masked (FAULTY), its neighbours decoded.
    after = len(rig.frames)
    eventually(lambda: any(f.complete for f in rig.frames[after:]), "a sample after the flood")
    frame: ForceFrame = next(f for f in rig.frames[after:] if f.complete)
    assert frame.reason[4] == Reason.FAULTY and frame.valid.sum() == 8
    assert host.health()[1].state == "operational" and host.health()[1].emcys >= flood



def test_answers_nobody_asked_for_are_kept_bounded(rig: Rig) -> None:
    """canopen queues every SDO answer (0x580 + ID) and every LSS answer (0x7E4) for as
    long as the network runs: a flood of them between transfers must not grow the host."""
    rig.serve(1, source(1, press({})))
    host = rig.start(config(PatchConfig(1)))
    assert host.wait_operational(timeout=WAIT_S)
    rig.spy.listeners.clear()
    flood = 2000
    with can.Bus(interface="virtual", channel=rig.channel) as flooder:
        for k in range(flood):
            flooder.send(can.Message(arbitration_id=0x7E4, data=bytes([0x44, k % 256]),
                                     is_extended_id=False))
        for k in range(flood):
            flooder.send(can.Message(arbitration_id=0x581, data=bytes([0x43, 0, 0x10, 0,
                                                                         k % 256, 0, 0, 0]),
                                     is_extended_id=False))
    sdo = host.patch(1).node.sdo
    eventually(lambda: sdo.dropped >= flood - 256, "the SDO answers handled", timeout=60.0)
    assert sdo.responses.qsize() <= 256 and host.network.lss.responses.qsize() <= 256
    assert host.health()[1].state == "operational"


def test_a_host_stopped_in_its_start_starts_again_and_configures(rig: Rig) -> None:
    from canbus.master.host import HostManager

    rig.serve(1, source(1, press({})))
    host = HostManager(rig.bus, config(PatchConfig(1), scan_ms=1500))
    starting = threading.Thread(target=host.start)
    starting.start()
    eventually(lambda: host.running, "the start under way")
    host.stop()  # in the scan: its SDO clients are halted
    starting.join(timeout=WAIT_S)
    assert not starting.is_alive() and not host.running
    rig.host = host
    host.start()
    assert host.wait_operational(timeout=WAIT_S)
