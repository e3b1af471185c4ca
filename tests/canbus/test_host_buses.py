"""The host on CAN FD, on several buses, following another master's SYNC, and tared by SDO:
simulated patches and outside canopen masters on virtual buses, in one process."""

# mypy: disable-error-code="no-untyped-call"
from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import can
import canopen
import numpy as np
import pytest
from canopen.sdo.exceptions import SdoAbortedError

from canbus.device.patch_server import PatchServer
from canbus.master.busconfig import BusConfig
from canbus.master.dataplane import ForceFrame
from canbus.master.host import HostManager
from canbus.master.hostconfig import HostConfig, PatchConfig
from canbus.od import load_od
from tests.support.rigs.host import eventually, expected, press, source
from tests.support.rigs.waiting import holds_for

FD = can.CanProtocol.CAN_FD


class Buses:
    """Named virtual channels, each with a spy recording every frame, and patch networks."""

    def __init__(self, prefix: str, names: list[str], *, fd: bool = False) -> None:
        self.prefix, self.fd = prefix, fd
        self.protocol = FD if fd else can.CanProtocol.CAN_20
        self.host_side = {n: self.bus(n) for n in names}
        self.spies = {n: self.bus(n) for n in names}
        self.seen: dict[str, list[can.Message]] = {n: [] for n in names}
        self.notifiers = [can.Notifier(self.spies[n], [self.seen[n].append], timeout=0.05)
                          for n in names]
        self.networks: list[canopen.Network] = []
        self.servers: list[PatchServer] = []

    def bus(self, name: str) -> can.BusABC:
        return can.Bus(interface="virtual", channel=f"{self.prefix}-{name}",
                       protocol=self.protocol)

    def network(self, name: str) -> canopen.Network:
        net = canopen.Network(self.bus(name))
        net.NOTIFIER_CYCLE = 0.05
        net.connect()
        self.networks.append(net)
        return net

    def serve(self, name: str, node_id: int, resistance: np.ndarray) -> None:
        server = PatchServer(self.network(name), source(node_id, resistance))
        server.start()
        self.servers.append(server)

    def close(self) -> None:
        for server in self.servers:
            server.stop()
        for net in self.networks:
            net.disconnect()
        for notifier in self.notifiers:
            notifier.stop(timeout=1.0)
        for bus in [*self.spies.values(), *self.host_side.values()]:
            bus.shutdown()


@pytest.fixture
def fd_bus(request: pytest.FixtureRequest) -> Iterator[Buses]:
    buses = Buses(request.node.name, ["skin"], fd=True)
    yield buses
    buses.close()


def _host(buses: Buses, config: HostConfig) -> tuple[HostManager, list[ForceFrame]]:
    frames: list[ForceFrame] = []
    host = HostManager(buses.host_side if len(buses.host_side) > 1 else
                       next(iter(buses.host_side.values())), config)
    host.on_forces(frames.append)
    return host, frames


def test_can_fd_a_whole_sample_in_one_frame_each_way(fd_bus: Buses) -> None:
    load = press({4: (0.3, -0.2, 2.5), 0: (0.0, 0.0, 0.8)})
    fd_bus.serve("skin", 1, load)
    config = HostConfig(patches=(PatchConfig(1),), scan_ms=100,
                        buses=(BusConfig(name="skin", fd=True),))
    consumer = fd_bus.network("skin")  # any CANopen master reads the forces
    host, frames = _host(fd_bus, config)
    with host:
        remote = consumer.add_node(canopen.RemoteNode(65, load_od("skin-forces", 65)))
        remote.tpdo.read()  # the mapping the host gave its force node, by SDO
        got = threading.Event()
        remote.tpdo[1].add_callback(lambda _: got.set())
        eventually(lambda: sum(f.complete for f in frames) >= 3, "complete samples")
        assert got.wait(2.0)
        forces = [v.raw for v in remote.tpdo[1]][:27]
        last = remote.tpdo[1]["SYNC counter answered"].raw
        cycle = next(f for f in reversed(frames) if f.sync_counter == last)
    want, _ = expected(load)
    np.testing.assert_allclose(frames[-1].force_N, want, rtol=1e-12)
    assert forces == [int(v) for v in np.rint(cycle.force_N * 1000).reshape(27)]
    answers = [m for m in fd_bus.seen["skin"] if m.arbitration_id == 0x181]
    published = [m for m in fd_bus.seen["skin"] if m.arbitration_id == 0x181 + 64]
    assert answers and all(m.is_fd and m.bitrate_switch and len(m.data) == 64 for m in answers)
    assert published and all(m.is_fd and len(m.data) == 64 for m in published)
    assert not any(m.arbitration_id in (0x281, 0x201) for m in fd_bus.seen["skin"])
    assert all(not m.is_fd for m in fd_bus.seen["skin"] if m.arbitration_id in (0x080, 0x701))


def test_a_stale_fd_answer_is_known_by_its_sync_counter(fd_bus: Buses) -> None:
    """A CAN FD answer names the SYNC it answers (0x2006): one to an earlier SYNC is late."""
    fd_bus.serve("skin", 1, press({}))
    config = HostConfig(patches=(PatchConfig(1),), scan_ms=100, sync_period_ms=20.0,
                        buses=(BusConfig(name="skin", fd=True),))
    host, frames = _host(fd_bus, config)
    with host:
        eventually(lambda: len(frames) >= 2, "samples")
        plane = host.dataplane
        answer = next(m for m in reversed(fd_bus.seen["skin"]) if m.arbitration_id == 0x181)
        stale = can.Message(arbitration_id=0x181, data=answer.data, is_fd=True,
                            is_extended_id=False, timestamp=time.time())
        stale.data[54] = (answer.data[54] + 100) % 240 + 1  # another SYNC's counter
        before = plane.stats.stale_answers
        plane.on_message_received(stale)
        assert plane.stats.stale_answers == before + 1


@pytest.fixture
def three(request: pytest.FixtureRequest) -> Iterator[Buses]:
    buses = Buses(request.node.name, ["a", "b", "arm"])
    yield buses
    buses.close()


def test_patches_on_two_skin_buses_and_every_force_node_on_the_arms(three: Buses) -> None:
    loads = {1: press({1: (0, 0, 1.0)}), 2: press({2: (0, 0, 2.0)}), 3: press({3: (0, 0, 3.0)})}
    three.serve("a", 1, loads[1])
    three.serve("a", 2, loads[2])
    three.serve("b", 3, loads[3])
    config = HostConfig(
        patches=(PatchConfig(1, bus="a", force_bus="arm"), PatchConfig(2, bus="a",
                 force_bus="arm"), PatchConfig(3, bus="b", force_bus="arm")),
        scan_ms=100, buses=(BusConfig("a"), BusConfig("b"), BusConfig("arm")))
    host, frames = _host(three, config)
    with host:
        eventually(lambda: {f.patch for f in frames if f.complete} == {1, 2, 3}, "all patches")
        health = host.health()
        per_bus = host.bus_stats()
    assert {n: h.bus for n, h in health.items()} == {1: "a", 2: "a", 3: "b"}
    for patch, load in loads.items():
        want, _ = expected(load)
        np.testing.assert_allclose([f for f in frames if f.patch == patch and f.complete][-1]
                                   .force_N, want, rtol=1e-12)
    syncs = {name: sum(m.arbitration_id == 0x080 for m in seen)
             for name, seen in three.seen.items()}
    assert syncs["a"] > 0 and syncs["b"] > 0 and syncs["arm"] == 0  # one SYNC per skin bus
    forces = {m.arbitration_id for m in three.seen["arm"]}
    assert {0x180 + 65, 0x180 + 66, 0x180 + 67} <= forces  # every force node on the arm's bus
    assert not any(0x181 <= m.arbitration_id <= 0x1FF and m.arbitration_id > 0x1C0
                   for m in three.seen["a"] + three.seen["b"])
    assert per_bus["a"]["patches"] == [1, 2] and per_bus["arm"]["force_nodes"] == [65, 66, 67]
    assert per_bus["arm"]["sync_cycles"] == 0 and per_bus["b"]["complete_samples"] > 0


def test_a_one_bus_host_refuses_a_config_of_several_buses(three: Buses) -> None:
    config = HostConfig(patches=(PatchConfig(1, bus="a"),), buses=(BusConfig("a"),
                                                                   BusConfig("b")))
    with pytest.raises(Exception, match="2 buses"):
        HostManager(three.host_side["a"], config)


@pytest.fixture
def one(request: pytest.FixtureRequest) -> Iterator[Buses]:
    buses = Buses(request.node.name, ["skin"])
    yield buses
    buses.close()


def test_external_sync_and_tare_by_sdo(one: Buses) -> None:
    """The arm's master produces SYNC; the host configures the patch and publishes on it;
    the master tares the patch by SDO: refused while loaded, done at rest."""
    pressed, rest = press({4: (0.0, 0.0, 1.5)}), press({})
    offset = rest * 1.0006  # the rubber crept: the patch reads ~0.03 N at rest
    samples = np.stack([pressed, offset])[:, None]
    from canbus.device.source import ArraySource

    class Switch(ArraySource):
        """Pressed until told, then at rest with an offset."""

        at_rest = False

        def read(self) -> np.ndarray:
            return samples[1 if self.at_rest else 0]

    src = Switch(samples, (1,))
    server = PatchServer(one.network("skin"), src)
    server.start()
    one.servers.append(server)
    master = one.network("skin")
    config = HostConfig(patches=(PatchConfig(1),), scan_ms=100, sync="external",
                        tare_threshold_N=0.2)
    host, frames = _host(one, config)
    with host:
        assert host.wait_operational(timeout=10.0)
        holds_for(lambda: frames == [], 0.1, what="no SYNC from anyone yet: nothing published")
        master.sync.start(0.01)
        try:
            eventually(lambda: sum(f.complete for f in frames) >= 3, "samples on its SYNC")
            remote = master.add_node(canopen.RemoteNode(65, load_od("skin-forces", 65)))
            with pytest.raises(SdoAbortedError) as refused:
                remote.sdo.download(0x2007, 0, b"\x01")
            assert refused.value.code == 0x0800_0022  # loaded: tare refused
            src.at_rest = True
            eventually(lambda: frames[-1].force_N[4, 2] < 0.05 and frames[-1].complete,
                       "the press released")
            assert np.abs(frames[-1].force_N).max() > 0.01  # the creep reads as a force
            remote.sdo.download(0x2007, 0, b"\x01")
            count = len(frames)
            eventually(lambda: len(frames) > count + 3, "samples after the tare")
            assert np.abs(frames[-1].force_N).max() < 3e-3  # near zero: a code's worth
            with pytest.raises(SdoAbortedError) as bad:
                remote.sdo.download(0x2007, 0, b"\x02")
            assert bad.value.code == 0x0609_0030
        finally:
            master.sync.stop()
        assert host.stats()["sync_overruns"] == 0 and host.sync.cycle > 0


def test_the_sniffer_and_the_view_read_can_fd_forces(fd_bus: Buses) -> None:
    """A host maps its own force nodes for CAN FD in place, with no SDO on the bus: a tool
    reading the bus adopts the one-frame mapping when a TPDO 1 arrives as a long FD frame."""
    from canbus.tools.forcereader import ForceReader
    from canbus.tools.pdo_dictionary import Dictionary
    from canbus.tools.services import ServiceDecoder

    load = press({4: (0.3, -0.2, 2.5)})
    fd_bus.serve("skin", 1, load)
    reader = ForceReader([65])
    samples: list = []
    reader.on_sample(samples.append)
    watcher = fd_bus.bus("skin")
    notifier = can.Notifier(watcher, [reader], timeout=0.05)
    config = HostConfig(patches=(PatchConfig(1),), scan_ms=100,
                        buses=(BusConfig(name="skin", fd=True),))
    host, frames = _host(fd_bus, config)
    try:
        with host:
            eventually(lambda: sum(f.complete for f in frames) >= 3, "complete samples")

            def read() -> bool:
                reader.process()
                return reader.samples >= 3

            eventually(read, "the reader's samples")
        reader.process()
    finally:
        notifier.stop(timeout=1.0)
        watcher.shutdown()
    assert reader.samples >= 3
    want, _ = expected(load)
    last = [f for f in frames if f.complete][-1]
    published = [m for m in fd_bus.seen["skin"] if m.arbitration_id == 0x181 + 64]
    text = ServiceDecoder(Dictionary()).describe_pdo(0x1C1, bytes(published[-1].data),
                                                      Dictionary().view(65))
    sent = [v / 1000 for v in np.rint(last.force_N * 1000).reshape(27)]
    assert f"F4z={sent[14]:+.3f} N" in text and "valid=9/9" in text  # all 27, one frame
    assert "SYNC counter answered=" in text
    np.testing.assert_allclose(last.force_N, want, rtol=1e-12)
    by_counter = {f.sync_counter: f for f in frames}
    assert samples and all(s.sync_counter is not None for s in samples)  # 0x2006 read
    for sample in [s for s in samples if s.complete][-3:]:
        mine = by_counter[sample.sync_counter]  # the host's own sample of that SYNC
        np.testing.assert_allclose(sample.force_N, np.rint(mine.force_N * 1000) / 1000,
                                   atol=1e-9)


def test_bit_errors_on_a_timed_bus_never_mix_a_sample(request: pytest.FixtureRequest) -> None:
    """The patches' node hits bit errors (retransmitted, as CAN does): every sample the host
    publishes complete is the decode of one whole answer; the rest are flagged."""
    from canbus.device.source import ArraySource

    loads = [press({k % 9: (0.1 * k, -0.05 * k, 0.5 + 0.2 * k)}) for k in range(12)]
    channel = f"timed-{request.node.name}"
    host_bus = can.Bus(interface="timed", channel=channel)
    patch_bus = can.Bus(interface="timed", channel=channel, error_probability=0.05,
                        error_seed=7)
    net = canopen.Network(patch_bus)
    net.NOTIFIER_CYCLE = 0.05
    net.connect()
    server = PatchServer(net, ArraySource(np.stack(loads)[:, None], (1,)))
    server.start()
    frames: list[ForceFrame] = []
    try:
        host = HostManager(host_bus, HostConfig(patches=(PatchConfig(1),), scan_ms=100,
                                                sync_period_ms=20.0))
        host.on_forces(frames.append)
        with host:
            eventually(lambda: len(frames) >= 40, "forty cycles")
        wire = host_bus.wire_stats()
    finally:
        server.stop()
        net.disconnect()
        host_bus.shutdown()
        patch_bus.shutdown()
    assert wire.error_frames > 0 and wire.retransmissions > 0  # the errors happened
    answers = [expected(load)[0] for load in loads]
    complete = [f for f in frames if f.complete]
    assert len(complete) > len(frames) // 2
    for frame in complete:
        assert any(np.allclose(frame.force_N, a, rtol=1e-12, atol=1e-12) for a in answers)


def test_a_bus_left_to_python_can_names_what_its_configuration_opens(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A config without interface opens what python-can's configuration names, and the
    messages say which, not "?:?"."""
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    monkeypatch.setenv("CAN_CHANNEL", "arm0")
    assert BusConfig().described == "virtual:arm0 (python-can's configuration)"
    assert BusConfig(channel="arm1").described == "virtual:arm1 (python-can's configuration)"
    assert BusConfig(interface="udp_multicast").described == "udp_multicast:?"
