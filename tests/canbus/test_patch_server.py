"""The patch server answers like a device: every SYNC with every TPDO once, in COB-ID order
per patch, patches in node-ID order, each answer one sample; on several buses each its own;
on the timed bus as fast as the wire takes them; on udp_multicast without its own echoes."""

from __future__ import annotations

import itertools
import sys
import threading
import time
from collections.abc import Callable, Iterator

import can
import canopen
import numpy as np
import pytest

from canbus import codes
from canbus.busload import TPDO_BASES
from canbus.device.nmt_slave import OPERATIONAL
from canbus.device.patch_node import ANSWERED, RESISTANCES, PatchNode
from canbus.device.patch_server import PatchServer
from canbus.device.source import ArraySource
from canbus.framebits import frame_bits
from canbus.pdo_codec import TPDO_COMM, TPDO_MAP, PdoCodec
from canbus.txmessage import TxMessage
from skin.constants import DEFAULT_CONSTANTS
from tests.support.rigs.waiting import wait_until

LSB = DEFAULT_CONSTANTS.resistance_lsb_ohm
SYNC = 0x080


def _samples(count: int, patches: int) -> np.ndarray:
    """(count, patches, 9, 3) ohms, every value different, so a code names its sample."""
    rng = np.random.default_rng(count * 100 + patches)
    return rng.uniform(900.0, 1900.0, (count, patches, 9, 3))


def _answer_ids(node_ids: list[int], tpdos: int = 7) -> list[int]:
    """Each patch's TPDO COB-IDs ascending, the patches in node-ID order."""
    return [base + n for n in sorted(node_ids) for base in sorted(TPDO_BASES[:tpdos])]


class Listener(can.Listener):
    """Every frame a bus receives, with a condition to wait on."""

    def __init__(self) -> None:
        self.frames: list[can.Message] = []
        self.changed = threading.Condition()

    def on_message_received(self, msg: can.Message) -> None:
        with self.changed:
            self.frames.append(msg)
            self.changed.notify_all()

    def wait_for(self, tpdos: int, timeout: float = 5.0) -> list[can.Message]:
        """Every frame so far, once ``tpdos`` TPDOs came (or ``timeout`` s passed)."""
        def enough() -> bool:
            return sum(0x180 <= m.arbitration_id < 0x500 for m in self.frames) >= tpdos

        with self.changed:
            self.changed.wait_for(enough, timeout)
            return list(self.frames)


class Master:
    """A raw python-can bus on a channel: sends NMT and SYNC, keeps what it receives."""

    def __init__(self, **kwargs: object) -> None:
        if kwargs["interface"] != "udp_multicast":  # it hands back its own frames anyway
            kwargs["receive_own_messages"] = True  # its SYNCs among the answers, in order
        self.bus = can.Bus(**kwargs)  # type: ignore[arg-type]
        self.seen = Listener()
        self.notifier = can.Notifier(self.bus, [self.seen], timeout=0.05)

    def start_all(self) -> None:
        self.bus.send(TxMessage.data_frame(0x000, b"\x01\x00"))

    def sync(self, counter: int) -> None:
        self.bus.send(TxMessage.data_frame(SYNC, bytes([counter])))

    def close(self) -> None:
        self.notifier.stop()
        self.bus.shutdown()


def _network(**kwargs: object) -> canopen.Network:
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.05
    network.connect(**kwargs)
    return network


def _operational(server: PatchServer, timeout: float = 30.0) -> None:
    wait_until(lambda: all(n.nmt.state == OPERATIONAL for n in server.nodes),
               what="the patches started", timeout=timeout)


def _answers(frames: list[can.Message]) -> list[tuple[int, list[can.Message]]]:
    """The frames after each SYNC: (its counter byte, the TPDOs until the next SYNC)."""
    out: list[tuple[int, list[can.Message]]] = []
    for msg in frames:
        if msg.arbitration_id == SYNC:
            out.append((msg.data[0], []))
        elif out and 0x180 <= msg.arbitration_id < 0x500:
            out[-1][1].append(msg)
    return out


def _codes_of(answer: list[can.Message], node_ids: list[int]) -> np.ndarray:
    """(patches, 27) codes of a classic answer, patch by patch in node-ID order, each patch's
    TPDOs in COB-ID order: TPDO 1, 5, 2, 6, 3, 7, 4 carry codes 1-4, 17-20, 5-8, ..."""
    out = np.zeros((len(node_ids), 27), dtype=np.int64)
    for j, n in enumerate(sorted(node_ids)):
        by_tpdo = {TPDO_BASES.index(m.arbitration_id - n): bytes(m.data) for m in answer
                   if m.arbitration_id - n in TPDO_BASES}
        raw = b"".join(by_tpdo[t] for t in range(7))
        out[j] = np.frombuffer(raw, dtype="<u2")
    return out


@pytest.fixture
def virtual(request: pytest.FixtureRequest) -> Iterator[tuple[canopen.Network, Master]]:
    channel = f"server-{request.node.name}"
    network = _network(interface="virtual", channel=channel)
    master = Master(interface="virtual", channel=channel)
    yield network, master
    master.close()
    network.disconnect()


@pytest.mark.parametrize("event_rate_hz", [0.0, 200.0])
def test_every_sync_is_answered_with_every_tpdo_once_in_order(
        virtual: tuple[canopen.Network, Master], event_rate_hz: float) -> None:
    network, master = virtual
    node_ids = [3, 1, 2]  # the source's order; the answer goes in node-ID order
    samples = _samples(8, len(node_ids))
    server = PatchServer(network, ArraySource(samples, tuple(node_ids)),
                         event_rate_hz=event_rate_hz)
    expected = _answer_ids(node_ids)
    syncs = 25
    with server:
        master.start_all()
        _operational(server)
        for k in range(1, syncs + 1):
            master.sync(k)
            master.seen.wait_for(k * len(expected))
    answers = _answers(master.seen.frames)
    assert [counter for counter, _ in answers] == list(range(1, syncs + 1))
    assert [[m.arbitration_id for m in got] for _, got in answers] == [expected] * syncs
    assert server.sync_count == syncs and server.frames_sent == syncs * len(expected)
    order = np.argsort(node_ids)
    served = codes.resistance_to_code(samples, LSB).reshape(len(samples), len(node_ids), 27)
    served = served[:, order]  # node-ID order
    picked = []
    for k, (_, got) in enumerate(answers, start=1):
        values = _codes_of(got, node_ids)
        same = [s for s in range(len(samples)) if np.array_equal(values, served[s])]
        assert len(same) == 1, f"SYNC {k}: the answer is not one sample of every patch"
        picked.append(same[0])
    if event_rate_hz == 0:  # every SYNC reads the next sample (start() read the first)
        assert picked == [k % len(samples) for k in range(1, syncs + 1)]


def test_a_can_fd_answer_is_one_frame_per_patch_naming_its_sync(request: pytest.FixtureRequest
                                                                ) -> None:
    channel = f"server-{request.node.name}"
    network = _network(interface="virtual", channel=channel, protocol=can.CanProtocol.CAN_FD)
    master = Master(interface="virtual", channel=channel, protocol=can.CanProtocol.CAN_FD)
    samples = _samples(4, 2)
    server = PatchServer(network, ArraySource(samples, (1, 2)))
    try:
        with server:
            for node in server.nodes:  # TPDO 1: all 27 codes and 0x2006 (the host's FD map)
                entries = [(RESISTANCES << 16) | (s << 8) | 16 for s in range(1, 28)]
                entries.append((ANSWERED << 16) | 8)
                node.store.store(TPDO_MAP, 0, len(entries))
                for s, raw in enumerate(entries, start=1):
                    node.store.store(TPDO_MAP, s, raw)
                for n in range(1, 7):
                    cob = int(node.store.value(TPDO_COMM + n, 1))
                    node.store.store(TPDO_COMM + n, 1, cob | 0x8000_0000)
                node.tpdo.reset()
            master.start_all()
            _operational(server)
            for k, counter in enumerate((7, 8, 240), start=1):
                master.sync(counter)
                master.seen.wait_for(2 * k)
    finally:
        master.close()
        network.disconnect()
    answers = _answers(master.seen.frames)
    assert [c for c, _ in answers] == [7, 8, 240]
    for k, (counter, got) in enumerate(answers, start=1):
        assert [m.arbitration_id for m in got] == [0x181, 0x182]
        for j, msg in enumerate(got):
            assert msg.is_fd and len(msg.data) == 64
            assert msg.data[54] == counter and bytes(msg.data[55:]) == bytes(9)
            np.testing.assert_array_equal(np.frombuffer(bytes(msg.data[:54]), "<u2"),
                                          codes.resistance_to_code(samples[k % 4, j],
                                                                   LSB).reshape(27))


def test_patches_on_several_buses_answer_their_own_bus_sync(
        request: pytest.FixtureRequest) -> None:
    names = [f"server-{request.node.name}-{k}" for k in range(2)]
    networks = [_network(interface="virtual", channel=name) for name in names]
    masters = [Master(interface="virtual", channel=name) for name in names]
    source = ArraySource(_samples(3, 5), (1, 2, 3, 4, 5))
    try:
        with pytest.raises(ValueError, match="event_rate_hz"):
            PatchServer(networks, source)
        server = PatchServer(networks, source, event_rate_hz=100.0)
        assert [[n.node_id for n in bus.nodes] for bus in server.buses] == [[1, 2, 3], [4, 5]]
        with server:
            masters[0].start_all()
            masters[1].start_all()
            _operational(server)
            masters[1].sync(1)
            masters[1].seen.wait_for(14)
            masters[0].sync(1)
            masters[0].seen.wait_for(21)
            time.sleep(0.05)  # pacing: a span for a second answer, were there one
    finally:
        for master in masters:
            master.close()
        for network in networks:
            network.disconnect()
    for master, ids in zip(masters, ([1, 2, 3], [4, 5]), strict=True):
        (answer,) = _answers(master.seen.frames)
        assert [m.arbitration_id for m in answer[1]] == _answer_ids(ids)
    assert [bus.syncs for bus in server.buses] == [1, 1]


def test_on_the_timed_bus_the_wire_sets_the_pace(request: pytest.FixtureRequest) -> None:
    """A transmit queue of 4 frames for an answer of 42: ``send`` waits for room, no frame is
    lost, and the frames leave one after another at the wire's pace, each after the one
    before it has had its whole time on the wire."""
    channel = f"server-{request.node.name}"
    master = Master(interface="timed", channel=channel)
    network = _network(interface="timed", channel=channel, tx_queue_size=4)
    node_ids = [1, 2, 3, 4, 5, 6]
    server = PatchServer(network, ArraySource(_samples(2, 6), tuple(node_ids)))
    try:
        with server:
            master.start_all()
            _operational(server)
            master.sync(1)
            frames = master.seen.wait_for(42)
    finally:
        network.disconnect()
        master.close()
    (answer,) = _answers(frames)
    got = answer[1]
    assert [m.arbitration_id for m in got] == _answer_ids(node_ids)
    for before, after in itertools.pairwise(got):
        wire_s = frame_bits(after.arbitration_id, bytes(after.data)).duration_s(1_000_000)
        assert after.timestamp - before.timestamp >= wire_s - 1e-6
    assert server.frames_sent == 42


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a Linux socket filter")
def test_on_udp_multicast_the_server_hears_neither_its_echo_nor_what_it_does_not_consume(
        udp_channel: str, udp_port: int) -> None:
    bus = {"interface": "udp_multicast", "channel": udp_channel, "port": udp_port}
    network = _network(**bus)
    master = Master(**bus)
    heard = Listener()
    client = _network(**bus)
    server = PatchServer(network, ArraySource(_samples(2, 1), (1,)), accept_only_consumed=True)
    try:
        with server:
            assert network.notifier is not None
            network.notifier.add_listener(heard)
            node = client.add_node(canopen.RemoteNode(1, server.nodes[0].store.object_dictionary))
            node.sdo.RESPONSE_TIMEOUT = 2.0
            assert node.sdo.upload(0x1018, 4)[:1] == b"\x01"  # SDO still reaches it
            master.start_all()
            _operational(server)
            master.bus.send(TxMessage.data_frame(0x1C1, bytes(8)))  # a force PDO, say
            master.sync(1)
            master.seen.wait_for(7)
            # the force PDO went before the SYNC: heard, it would be in before the SYNC
            wait_until(lambda: SYNC in {m.arbitration_id for m in heard.frames},
                       what="the server's listener had the SYNC")
    finally:
        client.disconnect()
        master.close()
        network.disconnect()
    assert [m.arbitration_id for m in _answers(master.seen.frames)[0][1]] == _answer_ids([1])
    assert sorted({m.arbitration_id for m in heard.frames}) == [0x000, SYNC, 0x601]


def _sdo_write(node: PatchNode, index: int, subindex: int, value: int) -> None:
    """A master's SDO download, as the node's SDO server runs it on canopen's network
    thread: validators, the store, the write callbacks; the device's lock is not taken."""
    var = node.store.object_dictionary[index][subindex]
    node.store.set_data(index, subindex, var.encode_raw(value), check_writable=True)


def _pdo_valid(node: PatchNode, pdo: int, valid: bool) -> None:
    cob = int(node.store.value(0x1800 + pdo - 1, 1)) & 0x7FF
    _sdo_write(node, 0x1800 + pdo - 1, 1, cob if valid else cob | 0x8000_0000)


def _remap_tpdo_1_to_status(node: PatchNode) -> None:
    _pdo_valid(node, 1, False)
    _sdo_write(node, 0x1A00, 0, 0)
    _sdo_write(node, 0x1A00, 1, 0x20040108)  # 0x2004 sub 1: taxel 0's status, 8 bits
    _sdo_write(node, 0x1A00, 0, 1)
    _pdo_valid(node, 1, True)


@pytest.mark.parametrize(("before", "remap"), [
    (lambda n: _pdo_valid(n, 7, False), lambda n: _pdo_valid(n, 7, True)),  # 6 -> 7 PDOs
    (lambda n: None, lambda n: _pdo_valid(n, 7, False)),  # 7 -> 6 PDOs
    (lambda n: None, _remap_tpdo_1_to_status),  # TPDO 1: 8 bytes -> 1 byte
], ids=["a-pdo-made-valid", "a-pdo-made-invalid", "a-pdo-remapped"])
def test_a_remap_by_sdo_while_a_sample_is_packed_keeps_sample_and_mapping_together(
        request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch,
        before: Callable[[PatchNode], None], remap: Callable[[PatchNode], None]) -> None:
    """The SDO write path does not take the device's lock: a remap can land between the
    packing of a sample's payloads and the reading of the mapping they are sent with. Here
    it lands there every time (the packing is wrapped to run the remap right after it): the
    sample keeps the mapping it was packed with, whole and consistent, and the next sample
    takes the new one. (Before, the sample thread died with an IndexError or sent each
    payload under another PDO's COB-ID.)"""
    from canbus.device import patch_server

    network = _network(interface="virtual", channel=f"server-{request.node.callspec.id}")
    server = PatchServer(network, ArraySource(_samples(4, 1), (1,)))
    node = server.nodes[0]
    before(node)
    packed_with = node.tpdo.codec
    pack = patch_server.pack_payloads
    remapped: list[bool] = []

    def pack_then_remap(*args: object, **kwargs: object) -> list[list[bytes]]:
        payloads = pack(*args, **kwargs)  # type: ignore[arg-type]
        if not remapped:
            remapped.append(True)
            remap(node)  # the master's write lands now
        return payloads

    monkeypatch.setattr(patch_server, "pack_payloads", pack_then_remap)
    try:
        with server:  # start() takes the first sample: the remap lands inside it
            assert remapped
            node.nmt.enter(OPERATIONAL)
            _check_sizes(server.answer(), packed_with)  # that sample, as a SYNC sends it
            server.on_sync(SYNC, bytearray(), 0.0)  # the next sample: the new mapping
            assert node.tpdo.codec is not packed_with
            _check_sizes(server.answer(), node.tpdo.codec)
    finally:
        network.disconnect()


def _check_sizes(messages: list[can.Message], codec: PdoCodec) -> None:
    """One message per valid PDO of ``codec``, each as long as its PDO maps."""
    size = {lay.cob_id: lay.size for lay in codec.layouts}
    assert sorted(m.arbitration_id for m in messages) == sorted(size)
    assert all(len(m.data) == size[m.arbitration_id] for m in messages), \
        [(hex(m.arbitration_id), len(m.data), size[m.arbitration_id]) for m in messages]
def test_a_mapping_written_while_samples_are_taken_never_stops_them(
        virtual: tuple[canopen.Network, Master]) -> None:
    """The host remaps a patch by SDO while the server's sample thread packs its TPDOs: a
    write between two reads of the mapping must neither send one mapping's payloads by the
    other's COB-IDs nor end the sample thread (its patches would answer with one frozen
    sample from then on)."""
    network, master = virtual
    server = PatchServer(network, ArraySource(_samples(8, 1), (1,)), event_rate_hz=2000.0)
    switch = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # thread switches everywhere, the write among them
    try:
        with server:
            master.start_all()
            _operational(server)
            store = server.nodes[0].store
            until = time.monotonic() + 1.0
            for k in itertools.count():  # TPDO 1 invalid, valid, ... as CiA 301's sequence
                if time.monotonic() > until:
                    break
                cob = 0x181 | (0x8000_0000 if k % 2 == 0 else 0)
                store.set_data(TPDO_COMM, 1, cob.to_bytes(4, "little"))
                for msg in server.answer():  # TPDO 7 (0x401) carries 3 codes, the others 4
                    assert len(msg.data) == (6 if msg.arbitration_id == 0x401 else 8)
            taken = server.samples
            wait_until(lambda: server.samples > taken, what="the sample thread still sampling")
    finally:
        sys.setswitchinterval(switch)


class _FailingSource(ArraySource):
    """Replays samples, then fails from its ``fails_at``-th read on."""

    def __init__(self, resistance_ohm: np.ndarray, node_ids: tuple[int, ...],
                 fails_at: int) -> None:
        super().__init__(resistance_ohm, node_ids)
        self.reads = 0
        self.fails_at = fails_at

    def read(self) -> np.ndarray:
        self.reads += 1
        if self.reads >= self.fails_at:
            raise RuntimeError("the simulated ADC stopped")
        return super().read()


@pytest.mark.parametrize("event_rate_hz", [0.0, 500.0])
def test_a_source_that_fails_halts_its_patches_with_an_emcy_instead_of_a_frozen_sample(
        virtual: tuple[canopen.Network, Master], event_rate_hz: float) -> None:
    """Once the source fails, each patch sends EMCY 0x6100 with its error register set and
    answers no SYNC: a master never decodes the last sample as a live one."""
    network, master = virtual
    node_ids = (1, 2)
    source = _FailingSource(_samples(8, len(node_ids)), node_ids, fails_at=4)
    server = PatchServer(network, source, event_rate_hz=event_rate_hz)
    with server:
        master.start_all()
        _operational(server)
        counter = 0
        while not server.failed.is_set():  # SYNCs make a SYNC-driven server read
            counter += 1
            master.sync(counter % 256)
            server.failed.wait(0.01)
            assert counter < 10_000, "the source never failed"
        wait_until(lambda: len([m for m in master.seen.frames
                                if 0x081 <= m.arbitration_id <= 0x0FF]) == len(node_ids),
                   what="one EMCY from each patch")
        emcys = [m for m in master.seen.frames if 0x081 <= m.arbitration_id <= 0x0FF]
        assert sorted(m.arbitration_id - 0x080 for m in emcys) == list(node_ids)
        assert {bytes(m.data[:3]) for m in emcys} == {b"\x00\x61\x81"}
        sent = server.frames_sent
        before = len(master.seen.frames)
        for k in range(5):
            master.sync(k)
        wait_until(lambda: len(master.seen.frames) >= before + 5, what="the five SYNCs")
        assert server.frames_sent == sent, "a halted patch answered a SYNC"
        assert [int(n.store.value(0x1003, 1)) & 0xFFFF for n in server.nodes] == [0x6100] * 2
    assert isinstance(server.failure, RuntimeError)
    assert "ADC stopped" in str(server.failure)
