from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import can
import canopen
import numpy as np
import pytest
from canopen.sdo.exceptions import SdoAbortedError

from canbus.device.nmt_slave import OPERATIONAL, PRE_OPERATIONAL, STOPPED
from canbus.device.patch_node import PatchNode
from canbus.device.patch_server import PatchServer
from canbus.device.source import ArraySource
from canbus.device.tpdo import TpdoTable
from skin.constants import DEFAULT_CONSTANTS
from skin.tripod import resistance_from_force
from tests.support.rigs.devicebus import DeviceBus, network
from tests.support.rigs.waiting import wait_until


def _resistances(samples: int = 4) -> np.ndarray:
    force = np.zeros((samples, 2, 9, 3))
    force[..., 2] = np.linspace(0.0, 4.0, samples)[:, None, None]
    return resistance_from_force(force, DEFAULT_CONSTANTS)[..., :1]  # z-only patches


class Bench(DeviceBus):
    """A patch server (patches 1 and 2) on the device side; node 1 seen from the master."""

    def __init__(self, channel: str, event_rate_hz: float = 0.0) -> None:
        super().__init__(channel)
        self.server = PatchServer(self.device, ArraySource(_resistances(), (1, 2)),
                                  event_rate_hz=event_rate_hz)
        self.server.start()
        od = self.server.nodes[0].store.object_dictionary
        self.node = self.master.add_node(canopen.RemoteNode(1, od))
        self.node.sdo.RESPONSE_TIMEOUT = 1.0

    def state(self, node: int, state: str) -> None:
        wait_until(lambda: self.server.nodes[node - 1].state == state,
                   what=f"node {node} {state}")

    def close(self) -> None:
        self.server.stop()
        super().close()


@pytest.fixture
def bench(request: pytest.FixtureRequest) -> Iterator[Bench]:
    with Bench(request.node.name) as b:
        yield b


@pytest.fixture
def events(request: pytest.FixtureRequest) -> Iterator[Bench]:
    """A bench whose server serves event-driven TPDOs every 5 ms (and reads a sample)."""
    with Bench(request.node.name, event_rate_hz=200.0) as b:
        yield b


def _count(cob_id: int, n: int) -> Callable[[list[can.Message]], bool]:
    return lambda got: sum(m.arbitration_id == cob_id for m in got) >= n


def _tpdos(n: int) -> Callable[[list[can.Message]], bool]:
    return lambda got: sum(0x180 <= m.arbitration_id < 0x580 for m in got) >= n


def _abort(node: canopen.RemoteNode, index: int, sub: int, data: bytes) -> int:
    with pytest.raises(SdoAbortedError) as err:
        node.sdo.download(index, sub, data)
    return int(err.value.code)


def test_sdo_abort_codes(bench: Bench) -> None:
    n = bench.node
    assert _abort(n, 0x1000, 0, b"\0\0\0\0") == 0x06010002  # read-only
    assert _abort(n, 0x3000, 0, b"\0") == 0x06020000  # no such object
    assert _abort(n, 0x2000, 28, b"\0\0") == 0x06090011  # no such subindex
    assert _abort(n, 0x1017, 0, b"\0\0\0") == 0x06070012  # too long
    assert _abort(n, 0x1017, 0, b"\0") == 0x06070013  # too short
    assert _abort(n, 0x1800, 2, b"\xf5") == 0x06090030  # transmission type 245
    assert _abort(n, 0x1A00, 1, b"\x10\x01\x00\x20") == 0x06010000  # mapping while PDO valid
    with pytest.raises(SdoAbortedError) as err:
        n.sdo.upload(0x3000, 0)
    assert err.value.code == 0x06020000


def test_malformed_frames_are_answered_or_ignored(bench: Bench) -> None:
    for data in (b"", b"\x40\x00\x10", bytes(9)):  # zero-length, short, over-long (FD)
        bench.spy.send(can.Message(arbitration_id=0x601, data=data, is_fd=len(data) > 8))
    bench.spy.send(can.Message(arbitration_id=0x601, data=b"\xe0" + bytes(7)))  # bad ccs
    bench.spy.send(can.Message(arbitration_id=0x601, data=b"\x60" + bytes(7)))  # stray segment
    bench.spy.send(can.Message(arbitration_id=0x000, data=b"\x01"))  # short NMT frame
    bench.spy.send(can.Message(arbitration_id=0x7E5, data=bytes(8)))  # unknown COB-ID
    answers = [m for m in bench.collect_until(
        lambda got: sum(m.arbitration_id == 0x581 for m in got) >= 2, what="two aborts")
        if m.arbitration_id == 0x581]
    answers += [m for m in bench.collect(0.1) if m.arbitration_id == 0x581]  # and no more
    assert [bytes(m.data[:1]) + bytes(m.data[4:]) for m in answers] == [
        b"\x80\x01\x00\x04\x05", b"\x80\x01\x00\x04\x05"]
    assert bench.server.nodes[0].state == PRE_OPERATIONAL
    assert bench.node.sdo[0x1018][2].raw == 1  # still serving


def test_nmt_sync_stop_and_reset(bench: Bench) -> None:
    bench.node.nmt.send_command(0x01)
    bench.state(1, OPERATIONAL)
    bench.master.sync.transmit()
    tpdos = [m for m in bench.collect_until(_tpdos(3), what="node 1's answer")
             if 0x180 <= m.arbitration_id < 0x580]
    tpdos += [m for m in bench.collect(0.1) if 0x180 <= m.arbitration_id < 0x580]
    assert sorted(m.arbitration_id for m in tpdos) == [0x181, 0x281, 0x381]  # node 1 only
    assert all(len(m.data) == 6 for m in tpdos)  # z-only: a grid row per TPDO
    bench.node.nmt.send_command(0x02)
    bench.state(1, STOPPED)
    bench.master.sync.transmit()
    assert not [m for m in bench.collect(0.2) if 0x180 <= m.arbitration_id < 0x580]
    bench.node.nmt.send_command(0x81)
    bench.collect_until(lambda got: any(m.arbitration_id == 0x701 and bytes(m.data) == b"\x00"
                                        for m in got), what="node 1's boot-up")
    assert bench.server.nodes[0].state == PRE_OPERATIONAL


def test_heartbeat_period_and_sdo_change(bench: Bench) -> None:
    """The heartbeat runs at the period 0x1017 says, changed by SDO (python-can's periodic
    task keeps the time: its accuracy is python-can's, not asserted on a shared machine)."""
    node = bench.server.nodes[0]
    for period_ms in (50, 100):
        bench.node.sdo[0x1017].raw = period_ms
        assert node.heartbeat.period_ms == period_ms
        assert node.heartbeat._task.period == period_ms / 1000.0
        bench.collect_until(lambda got: sum(m.arbitration_id == 0x701 and m.data == b"\x7f"
                                            for m in got) >= 3, what="three heartbeats")
    bench.node.sdo[0x1017].raw = 0  # 0 stops the heartbeat
    assert node.heartbeat._task is None


def test_remap_to_status_by_cia301_sequence(bench: Bench) -> None:
    sdo = bench.node.sdo
    sdo[0x1800][1].raw = 0x80000181
    sdo[0x1A00][0].raw = 0
    sdo[0x1A00][1].raw = 0x20040108
    sdo[0x1A00][2].raw = 0x20040208
    with pytest.raises(SdoAbortedError) as err:
        sdo[0x1A00][3].raw = 0x20020120  # R0 (UNSIGNED32 mOhm): not mappable
    assert err.value.code == 0x06040041
    sdo[0x1A00][0].raw = 2
    sdo[0x1800][1].raw = 0x181
    bench.node.nmt.send_command(0x01)
    bench.state(1, OPERATIONAL)
    bench.master.sync.transmit()
    first = [m for m in bench.collect_until(_count(0x181, 1), what="TPDO 1") +
             bench.collect(0.1) if m.arbitration_id == 0x181]
    assert [bytes(m.data) for m in first] == [b"\x00\x00"]


@pytest.mark.parametrize(("ohm", "status"), [(np.inf, 1), (0.0, 2), (-3.0, 2), (1e6, 3)],
                         ids=["open", "short", "negative", "saturated"])
def test_emcy_on_fault_and_recovery(bench: Bench, ohm: float, status: int) -> None:
    patch = bench.server.nodes[0]
    r = np.full((9, 1), 1000.0)
    r[4, 0] = ohm
    patch.update(r)
    assert bench.node.sdo[0x1001].raw == 0x81
    assert bench.node.sdo[0x2004][5].raw == status
    r[4, 0] = 1000.0
    patch.update(r)
    emcy = [bytes(m.data) for m in bench.collect_until(_count(0x81, 2), what="two EMCYs")
            + bench.collect(0.1) if m.arbitration_id == 0x81]
    assert emcy == [b"\x00\x50\x81\x04" + bytes([status]) + b"\x00\x00\x00",
                    b"\x00\x00\x00\x04\x00\x00\x00\x00"]
    assert bench.node.sdo[0x1001].raw == 0


def test_emcy_error_register_stays_set_until_the_last_fault_recovers(bench: Bench) -> None:
    patch = bench.server.nodes[0]
    r = np.full((9, 1), 1000.0)
    r[2, 0] = 0.0  # short
    patch.update(r)
    r[7, 0] = 4000.0  # beyond 0xFFFE * 0.05 ohm: saturated
    patch.update(r)
    r[2, 0] = 1000.0
    patch.update(r)
    r[7, 0] = 1000.0
    patch.update(r)
    emcy = [bytes(m.data) for m in bench.collect_until(_count(0x81, 4), what="four EMCYs")
            + bench.collect(0.1) if m.arbitration_id == 0x81]
    assert emcy == [b"\x00\x50\x81\x02\x02\x00\x00\x00", b"\x00\x50\x81\x07\x03\x00\x00\x00",
                    b"\x00\x00\x81\x02\x00\x00\x00\x00", b"\x00\x00\x00\x07\x00\x00\x00\x00"]


def _event_driven(node: canopen.RemoteNode, pdo: int, trans: int, *, inhibit_100us: int = 0,
                  timer_ms: int = 0) -> None:
    """Make TPDO ``pdo`` event-driven the CiA 301 way: invalidate, set, validate."""
    comm = node.sdo[0x1800 + pdo - 1]
    cob_id = comm[1].raw
    comm[1].raw = cob_id | 0x8000_0000
    comm[2].raw = trans
    comm[3].raw = inhibit_100us
    comm[5].raw = timer_ms
    comm[1].raw = cob_id


def _tpdo_times(frames: list[can.Message], cob_id: int) -> np.ndarray:
    return np.array([m.timestamp for m in frames if m.arbitration_id == cob_id])


def _tpdo_table(trans: int, *, inhibit_100us: int = 0, timer_ms: int = 0) -> TpdoTable:
    """A patch's TPDO table with TPDO 1 event-driven, the CiA 301 way (by SDO writes)."""
    node = PatchNode(1)
    comm = node.store.object_dictionary[0x1800]
    for sub, value in ((1, 0x8000_0181), (2, trans), (3, inhibit_100us), (5, timer_ms),
                       (1, 0x181)):
        node.store.set_data(0x1800, sub, comm[sub].encode_raw(value), check_writable=True)
    return node.tpdo


@pytest.mark.parametrize("trans", [254, 255])
def test_the_event_timer_sends_every_period_of_the_clock_changed_or_not(trans: int) -> None:
    table = _tpdo_table(trans, timer_ms=50)
    same = [bytes(6)] * 7
    sent = [k for k in range(0, 301) if 0 in table.due_on_event(k / 1000.0, same)]
    assert sent == [0, 50, 100, 150, 200, 250, 300]  # ms of the caller's clock


def test_the_inhibit_time_spaces_changes_on_the_clock() -> None:
    table = _tpdo_table(255, inhibit_100us=400)
    sent = [k for k in range(0, 200, 5)  # a new payload every 5 ms tick
            if 0 in table.due_on_event(k / 1000.0, [k.to_bytes(6, "little")] * 7)]
    assert sent == [0, 40, 80, 120, 160]
    assert table.due_on_event(0.300, [(195).to_bytes(6, "little")] * 7) == [0]  # changed
    assert table.due_on_event(0.400, [(195).to_bytes(6, "little")] * 7) == []  # unchanged


@pytest.mark.parametrize("trans", [254, 255])
def test_event_driven_tpdos_flow_and_stop_silences_them(events: Bench, trans: int) -> None:
    _event_driven(events.node, 1, trans, timer_ms=50)
    started = time.monotonic()
    events.node.nmt.send_command(0x01)
    frames = events.collect_until(_count(0x181, 4), what="four timed TPDOs")
    span = time.monotonic() - started
    # never faster than the timer, however the machine runs (the rate itself: above)
    assert len(_tpdo_times(frames, 0x181)) <= span / 0.050 + 1  # any machine: an upper bound
    assert not [m for m in frames if m.arbitration_id in (0x281, 0x381)]  # still on SYNC
    events.node.nmt.send_command(0x02)
    events.state(1, STOPPED)
    events.collect(0.06)  # what the sample thread was sending as the stop came
    assert not [m for m in events.collect(0.25) if 0x180 <= m.arbitration_id < 0x580]
    events.node.nmt.send_command(0x01)
    events.collect_until(_count(0x181, 2), what="TPDOs again after NMT start")


def test_inhibit_time_spaces_tpdos_on_change(events: Bench) -> None:
    # The source changes every 5 ms tick; without the inhibit time every tick would send.
    _event_driven(events.node, 2, 255, inhibit_100us=400)
    started = time.monotonic()
    events.node.nmt.send_command(0x01)
    frames = events.collect_until(_count(0x281, 6), what="six TPDOs on change")
    span = time.monotonic() - started
    assert len(_tpdo_times(frames, 0x281)) <= span / 0.040 + 1  # any machine: an upper bound


def test_event_driven_without_timer_or_change_sends_once(events: Bench) -> None:
    events.server.source = ArraySource(_resistances(1), (1, 2))  # a constant signal
    _event_driven(events.node, 3, 254)
    events.node.nmt.send_command(0x01)
    events.collect_until(_count(0x381, 1), what="the first TPDO")
    ticks = events.server.samples
    wait_until(lambda: events.server.samples >= ticks + 20, what="20 more samples")
    assert not _tpdo_times(events.collect(0.05), 0x381).size  # no change: no more


def test_a_heartbeat_period_written_during_the_boot_leaves_one_heartbeat(
        request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> None:
    """A master writes 0x1017 the moment it hears the boot-up, while the node is still
    starting its heartbeat: one heartbeat task remains, at the written period."""
    import threading

    from canbus.device.patch_node import PatchNode

    net = network(request.node.name)
    node = PatchNode(1)
    tasks: list[canopen.network.PeriodicMessageTask] = []
    send_periodic = net.send_periodic
    booted = threading.Event()

    def slow_send_periodic(*args: object, **kwargs: object) -> canopen.network.PeriodicMessageTask:
        booted.set()  # the boot-up is out: the master's write comes now
        time.sleep(0.05)  # pacing: holds the boot inside the window the write lands in
        task = send_periodic(*args, **kwargs)  # type: ignore[arg-type]
        tasks.append(task)
        return task

    monkeypatch.setattr(net, "send_periodic", slow_send_periodic)
    writer = threading.Thread(target=lambda: booted.wait(5.0) and node.store.set_data(
        0x1017, 0, (50).to_bytes(2, "little")))
    writer.start()
    try:
        node.attach(net)
        writer.join()
        live = [task for task in tasks if not task._task.stopped]
        assert len(tasks) == 2 and live == [node.heartbeat._task]
        assert node.heartbeat.period_ms == 50
    finally:
        node.detach()
        net.disconnect()
