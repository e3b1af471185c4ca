"""LSS (CiA 305) in the patch node, against canopen's LssMaster and byte-exact traces; the
fastscan walk of ``skin lss scan`` against any set of identities (hypothesis)."""

from __future__ import annotations

import json
import struct
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import can
import canopen
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canbus.device.lss_slave import CONFIGURATION, WAITING, LssSlave
from canbus.device.nv_store import NvStore
from canbus.device.patch_node import PatchNode
from canbus.device.patch_server import PatchServer
from canbus.identity import Identity
from canbus.master.lss_assign import assign
from canbus.master.lss_scan import Fastscan, lss_scan, unconfigured
from canbus.od import load_od
from canbus.tools.lss_names import describe_lss
from skin.cli import main
from tests.support.rigs.devicebus import DeviceBus, network
from tests.support.rigs.host import Rest

SERIALS = [0x0000_1003, 0x0000_1001, 0x0042_0007]
VENDOR, PRODUCT, REVISION = 0, 1, 0x0001_0000


class Lab(DeviceBus):
    """Unconfigured patches (``SERIALS``) served on a virtual bus, a master beside them and
    every frame the spy took in :attr:`seen`."""

    def __init__(self, channel: str, state_dir: Path | None = None,
                 unconfigured: bool = True) -> None:
        super().__init__(channel)
        self.taken: list[can.Message] = []
        nv = None if state_dir is None else \
            (lambda identity: NvStore.in_dir(state_dir, "patch", identity))
        self.server = PatchServer(self.device, Rest(len(SERIALS)), serials=SERIALS,
                                  unconfigured=unconfigured, nv=nv)
        self.server.start()

    def request(self, *data: int) -> None:
        self.master.send_message(0x7E5, bytes(data).ljust(8, b"\0"))

    def answer(self, cs: int) -> bytes:
        msg = self.wait_for(lambda m: m.arbitration_id == 0x7E4 and m.data[0] == cs and
                            m not in self.taken, what=f"an LSS answer 0x{cs:02X}")
        self.taken.append(msg)
        return bytes(msg.data)

    def booted(self, node_id: int) -> None:
        self.wait_for(lambda m: m.arbitration_id == 0x700 + node_id and bytes(m.data) == b"\x00",
                      what=f"node {node_id}'s boot-up")

    def close(self) -> None:
        self.server.stop()
        super().close()


@pytest.fixture
def lab(request: pytest.FixtureRequest) -> Iterator[Lab]:
    with Lab(request.node.name) as lab:
        yield lab


def test_an_unconfigured_patch_sends_nothing_and_answers_lss(lab: Lab) -> None:
    lab.request(0x4C)  # identify non-configured remote slave: every one of them answers
    answers = [lab.answer(0x50) for _ in SERIALS]
    assert all(a == b"\x50" + bytes(7) for a in answers)
    # nothing else came before those answers: no boot-up, heartbeat, EMCY or TPDO
    assert all(m.arbitration_id in (0x7E4, 0x7E5) for m in lab.seen)
    assert all(not node.configured for node in lab.server.nodes)


def test_fast_scan_finds_the_smallest_identity_and_the_host_assigns_it(lab: Lab) -> None:
    found, identity = lab.master.lss.fast_scan()
    assert found and identity == [VENDOR, PRODUCT, REVISION, min(SERIALS)]
    lab.master.lss.configure_node_id(9)
    lab.master.lss.send_switch_state_global(lab.master.lss.WAITING_STATE)
    lab.booted(9)
    node = lab.master.add_node(canopen.RemoteNode(9, load_od("skin-patch", 9)))
    assert node.sdo[0x1018][4].raw == min(SERIALS)
    assert node.sdo[0x1008].raw == "canskin tactile patch"
    # the next scan finds the next smallest: the configured one takes part no more
    found, identity = lab.master.lss.fast_scan()
    assert found and identity[3] == sorted(SERIALS)[1]
    lab.master.lss.send_switch_state_global(lab.master.lss.WAITING_STATE)


def test_selective_switch_inquiries_and_configuration_byte_exact(lab: Lab,
                                                                 tmp_path: Path) -> None:
    serial = SERIALS[2]
    for cs, value in zip((0x40, 0x41, 0x42, 0x43), (VENDOR, PRODUCT, REVISION, serial),
                         strict=True):
        lab.request(cs, *struct.pack("<I", value))
    assert lab.answer(0x44) == b"\x44" + bytes(7)
    node = next(n for n in lab.server.nodes if n.identity.serial == serial)
    assert node.lss is not None and node.lss.state == CONFIGURATION
    for cs, value in ((0x5A, VENDOR), (0x5B, PRODUCT), (0x5C, REVISION), (0x5D, serial)):
        lab.request(cs)
        assert lab.answer(cs) == bytes([cs]) + struct.pack("<I", value) + bytes(3)
    lab.request(0x5E)
    assert lab.answer(0x5E) == b"\x5e\xff" + bytes(6)
    for bad in (0, 128, 0xFE):
        lab.request(0x11, bad)
        assert lab.answer(0x11) == b"\x11\x01" + bytes(6)  # node-ID out of range
    lab.request(0x13, 0, 5)
    assert lab.answer(0x13) == b"\x13\x01" + bytes(6)  # index 5 is reserved
    lab.request(0x13, 1, 0)
    assert lab.answer(0x13) == b"\x13\x01" + bytes(6)  # table 1 does not exist
    lab.request(0x13, 0, 2)
    assert lab.answer(0x13) == b"\x13\x00" + bytes(6)  # 500 kbit/s
    lab.request(0x15, 10, 0)  # activate after 10 ms: no answer
    lab.request(0x11, 42)
    assert lab.answer(0x11) == b"\x11\x00" + bytes(6)
    lab.request(0x04, 0)  # back to waiting: an unconfigured patch boots with its node-ID
    lab.booted(42)
    assert node.node_id == 42 and node.lss.state == WAITING and node.lss.bit_timing == 2
    assert not any(m.arbitration_id == 0x700 + 42 for m in lab.seen[:-1])


def test_identify_remote_slave_answers_from_every_patch_in_the_ranges(lab: Lab) -> None:
    low, high = sorted(SERIALS)[:2]
    for cs, value in zip(range(0x46, 0x4C), (VENDOR, PRODUCT, 0, REVISION, low, high),
                         strict=True):
        lab.request(cs, *struct.pack("<I", value))
    assert [lab.answer(0x4F) for _ in range(2)] == [b"\x4f" + bytes(7)] * 2
    # a range that holds no serial number: the request of the next identify is answered
    # by all three, and no fourth answer from the empty range came before it
    for cs, value in zip(range(0x46, 0x4C), (VENDOR, PRODUCT, 0, REVISION, 0, 0x10),
                         strict=True):
        lab.request(cs, *struct.pack("<I", value))
    lab.request(0x4C)
    [lab.answer(0x50) for _ in SERIALS]
    assert sum(m.arbitration_id == 0x7E4 and m.data[0] == 0x4F for m in lab.seen) == 2


def test_a_configured_patch_takes_a_new_node_id_at_reset_communication(lab: Lab) -> None:
    done = assign(lab.master, SERIALS[0], 5)
    assert done.previous is None
    lab.booted(5)
    done = assign(lab.master, SERIALS[0], 6, store=False)
    assert done.previous == 5  # assign reset it (NMT reset communication to node 5)
    lab.booted(6)
    node = next(n for n in lab.server.nodes if n.identity.serial == SERIALS[0])
    assert node.node_id == 6 and node.configured


def test_skin_lss_scan_lists_configured_and_waiting_patches(lab: Lab, tmp_path: Path,
                                                            request: pytest.FixtureRequest,
                                                            capsys: pytest.CaptureFixture[str]
                                                            ) -> None:
    assign(lab.master, SERIALS[1], 3)
    lab.booted(3)
    out = tmp_path / "scan.json"
    assert main(["lss", "scan", "--json", str(out), "-i", "virtual",
                 "-c", request.node.name]) == 0
    nodes = json.loads(out.read_text())["nodes"]
    assert [(n["node_id"], n["serial"]) for n in nodes] == \
        [(3, SERIALS[1]), (None, SERIALS[0]), (None, SERIALS[2])]
    assert all(n["product"] == PRODUCT and n["kind"] == "patch" for n in nodes)
    assert "3 nodes: 1 configured, 2 waiting for LSS" in capsys.readouterr().out
    # the scan configured nobody
    assert sum(n.configured for n in lab.server.nodes) == 1


def test_skin_lss_assign_stores_the_node_id(request: pytest.FixtureRequest, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    with Lab(request.node.name, state_dir=tmp_path) as lab:
        assert main(["lss", "assign", hex(SERIALS[2]), "12", "--store", "-i", "virtual",
                     "-c", request.node.name]) == 0
        assert "-> node 12, stored" in capsys.readouterr().out
        lab.booted(12)
    stored = json.loads((tmp_path / f"patch-{SERIALS[2]:08x}.json").read_text())
    assert stored["lss"] == {"node_id": 12, "bit_timing": None}
    # after a power cycle it boots with it, the others still wait
    with Lab(request.node.name + "-again", state_dir=tmp_path) as again:
        again.booted(12)
        assert [n.node_id for n in again.server.nodes if n.configured] == [12]


def test_skin_lss_assign_names_a_serial_nobody_has(request: pytest.FixtureRequest,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    with Lab(request.node.name):
        assert main(["lss", "assign", "0x77", "12", "-i", "virtual",
                     "-c", request.node.name]) != 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "0x00000077" in err


# --- the fastscan walk against any identities, on an in-memory bus --------------------

class MemoryNetwork:
    """A canopen-like network for LSS alone: requests reach every patch at once, answers
    are queued for the subscriber of 0x7E4."""

    def __init__(self, patches: list[PatchNode]) -> None:
        self.patches = patches
        self.subscribers: dict[int, list[Callable[[int, bytearray, float], None]]] = {}
        for patch in patches:
            assert patch.lss is not None
            patch.lss.network = self  # type: ignore[assignment]

    def subscribe(self, cob_id: int, callback: Callable[[int, bytearray, float], None]) -> None:
        self.subscribers.setdefault(cob_id, []).append(callback)

    def unsubscribe(self, cob_id: int, callback: Callable[[int, bytearray, float], None]
                    ) -> None:
        self.subscribers[cob_id].remove(callback)

    def send_message(self, cob_id: int, data: bytes) -> None:
        if cob_id == 0x7E5:
            for patch in self.patches:
                assert patch.lss is not None
                patch.lss.on_request(cob_id, bytearray(data), 0.0)
        for callback in self.subscribers.get(cob_id, []):
            callback(cob_id, bytearray(data), 0.0)


_POOL = [PatchNode(0xFF, serial=k) for k in range(4)]
identities = st.tuples(st.integers(0, 3), st.integers(0, 0xFFFF_FFFF), st.integers(0, 2),
                       st.integers(0, 0xFFFF_FFFF))


@settings(max_examples=25)
@given(st.lists(identities, min_size=0, max_size=4, unique=True))
def test_the_fastscan_walk_lists_every_waiting_identity(found: list[tuple[int, ...]]) -> None:
    patches = []
    for k, (vendor, product, revision, serial) in enumerate(found):
        patch = _POOL[k]
        patch.identity = Identity(vendor, product, revision, serial)
        patch.lss = LssSlave(patch)
        patches.append(patch)
    network = MemoryNetwork(patches)
    listed = unconfigured(network, timeout_s=0.0005, thorough=True)  # type: ignore[arg-type]
    assert listed == [Identity(*i) for i in sorted(found)]
    assert all(p.lss is not None and p.lss.state == WAITING for p in patches)


class LateNetwork(MemoryNetwork):
    """Answers reach the master late, on a thread of their own: ``stagger_s`` apart (the
    patches of one ``skin sim run`` answer one after the other, from another process), and
    each heard a second time ``echo_s`` later when ``echo_s`` is given (a path that
    delivers a frame twice)."""

    def __init__(self, patches: list[PatchNode], stagger_s: float,
                 echo_s: float | None = None) -> None:
        super().__init__(patches)
        self.stagger_s, self.echo_s = stagger_s, echo_s
        self.burst = 0
        self.timers: list[threading.Timer] = []

    def send_message(self, cob_id: int, data: bytes) -> None:
        if cob_id == 0x7E5:
            self.burst = 0
            super().send_message(cob_id, data)
            return
        self.burst += 1
        delays = [self.burst * self.stagger_s]
        if self.echo_s is not None:
            delays.append(delays[0] + self.echo_s)
        for delay in delays:
            timer = threading.Timer(delay, super().send_message, (cob_id, bytes(data)))
            self.timers.append(timer)
            timer.start()


@pytest.mark.parametrize(("stagger_s", "echo_s"), [(0.004, None), (0.001, 0.03)],
                         ids=["answers one after the other", "every answer heard twice"])
def test_late_answers_invent_no_node(stagger_s: float, echo_s: float | None) -> None:
    serials = [0x5100_0001, 0x5100_0002, 0x5100_0003, 0x5100_0008]
    patches = [PatchNode(0xFF, serial=serial) for serial in serials]
    network = LateNetwork(patches, stagger_s, echo_s)
    try:
        listed = unconfigured(network, timeout_s=0.05)  # type: ignore[arg-type]
    finally:
        for timer in network.timers:
            timer.cancel()
    assert listed == [Identity(VENDOR, PRODUCT, REVISION, s) for s in serials]
    assert all(p.lss is not None and p.lss.state == WAITING for p in patches)


lss_frames = st.one_of(
    st.binary(min_size=0, max_size=9),
    st.tuples(st.sampled_from([0x04, 0x11, 0x13, 0x15, 0x17, 0x40, 0x41, 0x42, 0x43, 0x46,
                               0x47, 0x48, 0x49, 0x4A, 0x4B, 0x4C, 0x51, 0x5A, 0x5B, 0x5C,
                               0x5D, 0x5E, 0x80, 0xFF]),
              st.binary(min_size=7, max_size=7)).map(lambda t: bytes([t[0]]) + t[1]))
ANSWERS = {0x11, 0x13, 0x17, 0x44, 0x4F, 0x50, 0x5A, 0x5B, 0x5C, 0x5D, 0x5E}


@settings(max_examples=30)
@given(st.lists(lss_frames, max_size=40))
def test_any_lss_sequence_keeps_the_slave_sound(frames: list[bytes]) -> None:
    patch = PatchNode(0xFF, serial=0x1001)
    sent: list[bytes] = []
    network = MemoryNetwork([patch])
    network.subscribe(0x7E4, lambda cob, data, ts: sent.append(bytes(data)))
    lss = patch.lss
    assert lss is not None
    for frame in frames:
        lss.on_request(0x7E5, bytearray(frame), 0.0)
        assert lss.state in (WAITING, CONFIGURATION)
        assert patch.node_id == 0xFF or 1 <= patch.node_id <= 127
        assert 1 <= lss.pending_node_id <= 127 or lss.pending_node_id == 0xFF
    assert all(len(a) == 8 and a[0] in ANSWERS for a in sent)
    # whatever came before, the LSS master's own fastscan still finds it and configures it
    lss.on_request(0x7E5, bytearray(b"\x04\x00" + bytes(6)), 0.0)
    if patch.node_id == 0xFF and lss.pending_node_id == 0xFF:  # else it takes a node-ID
        assert unconfigured(network, timeout_s=0.0005, thorough=True) == \
            [Identity(VENDOR, PRODUCT, REVISION, 0x1001)]


@pytest.mark.parametrize(("data", "text"), [
    ("0400000000000000", "switch state global: waiting"),
    ("4301100000000000", "switch state selective serial 0x00001001"),
    ("1105000000000000", "configure node-ID 5"),
    ("1101000000000000", "configure node-ID: node-ID out of range"),
    ("1302000000000000", "configure bit timing: error 2"),
    ("1700000000000000", "store configuration: ok"),
    ("5100000000801f00", "fastscan id 0x00000000 confirm sub 31 next 0"),
    ("5101100000000303", "fastscan id 0x00001001 bit 0 sub 3 next 3"),
    ("5eff000000000000", "inquire node-ID: 0xFF (unconfigured)"),
    ("4f00000000000000", "identify: a slave matches"),
    ("0102", "01 02 (length 2: not an LSS frame)"),
])
def test_the_sniffer_names_lss_services(data: str, text: str) -> None:
    raw = bytes.fromhex(data)
    answer = data[:2] in ("11", "13", "17", "5e", "4f") and not text.startswith("configure "
                                                                                  "node-ID 5")
    assert describe_lss(0x7E4 if answer else 0x7E5, raw) == text


def test_lss_scan_on_an_empty_bus_is_empty(request: pytest.FixtureRequest) -> None:
    net = network(request.node.name)
    try:
        assert lss_scan(net, timeout_s=0.05, scan_s=0.05) == []
    finally:
        net.disconnect()



class StaleNetwork(MemoryNetwork):
    """After every request, stale answers arrive too: a fastscan or identify answer (0x4F)
    to an earlier request, and an answer of the request's own kind from another node."""

    def send_message(self, cob_id: int, data: bytes) -> None:
        super().send_message(cob_id, data)
        if cob_id == 0x7E5:
            for callback in self.subscribers.get(0x7E4, []):
                callback(0x7E4, bytearray(b"\x4f" + bytes(7)), 0.0)
                callback(0x7E4, bytearray(struct.pack("<BI3x", data[0], 0x5100_0009)), 0.0)


def test_only_a_node_telling_its_own_identity_back_confirms_it() -> None:
    """The walk's last check: with stale answers after every request, an identity nobody
    has is refused and each real one confirmed, and every node is left waiting."""
    serials = [0x5100_0001, 0x5100_0008]
    patches = [PatchNode(0xFF, serial=serial) for serial in serials]
    scan_ = Fastscan(StaleNetwork(patches), timeout_s=0.01)  # type: ignore[arg-type]
    with scan_.listening():
        for serial in (0x5100_0009, 0x5100_0000, *serials):
            found = scan_.present(Identity(VENDOR, PRODUCT, REVISION, serial))
            assert found == (serial in serials), hex(serial)
    assert all(p.lss is not None and p.lss.state == WAITING for p in patches)
