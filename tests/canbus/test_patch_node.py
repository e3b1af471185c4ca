from __future__ import annotations

import queue
import time
from collections.abc import Iterator

import can
import canopen
import numpy as np
import pytest
from canopen.sdo.exceptions import SdoAbortedError

from canbus.nmt_slave import OPERATIONAL, PRE_OPERATIONAL, STOPPED
from canbus.patch_server import PatchServer
from canbus.source import ArraySource
from skin.constants import DEFAULT_CONSTANTS
from skin.tripod import resistance_from_force


def _resistances(samples: int = 4) -> np.ndarray:
    force = np.zeros((samples, 2, 9, 3))
    force[..., 2] = np.linspace(0.0, 4.0, samples)[:, None, None]
    return resistance_from_force(force, DEFAULT_CONSTANTS)[..., :1]  # z-only patches


class Bench:
    def __init__(self, channel: str) -> None:
        self.device = canopen.Network()
        self.device.connect(interface="virtual", channel=channel)
        self.master = canopen.Network()
        self.master.connect(interface="virtual", channel=channel)
        self.raw = can.Bus(interface="virtual", channel=channel)
        self.frames: queue.Queue[can.Message] = queue.Queue()
        self.notifier = can.Notifier(self.raw, [self.frames.put])
        self.server = PatchServer(self.device, ArraySource(_resistances(), (1, 2)))
        self.server.start()
        od = self.server.nodes[0].store.object_dictionary
        self.node = self.master.add_node(canopen.RemoteNode(1, od))
        self.node.sdo.RESPONSE_TIMEOUT = 1.0

    def collect(self, seconds: float) -> list[can.Message]:
        end, got = time.monotonic() + seconds, []
        while (left := end - time.monotonic()) > 0:
            try:
                got.append(self.frames.get(timeout=left))
            except queue.Empty:
                break
        return got

    def close(self) -> None:
        self.server.stop()
        self.notifier.stop()
        self.raw.shutdown()
        self.master.disconnect()
        self.device.disconnect()


@pytest.fixture
def bench(request: pytest.FixtureRequest) -> Iterator[Bench]:
    b = Bench(request.node.name)
    yield b
    b.close()


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
        bench.raw.send(can.Message(arbitration_id=0x601, data=data, is_fd=len(data) > 8))
    bench.raw.send(can.Message(arbitration_id=0x601, data=b"\xe0" + bytes(7)))  # bad ccs
    bench.raw.send(can.Message(arbitration_id=0x601, data=b"\x60" + bytes(7)))  # stray segment
    bench.raw.send(can.Message(arbitration_id=0x000, data=b"\x01"))  # short NMT frame
    bench.raw.send(can.Message(arbitration_id=0x7E5, data=bytes(8)))  # unknown COB-ID
    answers = [m for m in bench.collect(0.3) if m.arbitration_id == 0x581]
    assert [bytes(m.data[:1]) + bytes(m.data[4:]) for m in answers] == [
        b"\x80\x01\x00\x04\x05", b"\x80\x01\x00\x04\x05"]
    assert bench.server.nodes[0].state == PRE_OPERATIONAL
    assert bench.node.sdo[0x1018][2].raw == 1  # still serving


def test_nmt_sync_stop_and_reset(bench: Bench) -> None:
    bench.node.nmt.send_command(0x01)
    time.sleep(0.05)
    assert bench.server.nodes[0].state == OPERATIONAL
    bench.master.sync.transmit()
    tpdos = [m for m in bench.collect(0.2) if 0x180 <= m.arbitration_id < 0x580]
    assert sorted(m.arbitration_id for m in tpdos) == [0x181, 0x281, 0x381]  # node 1 only
    assert all(len(m.data) == 6 for m in tpdos)  # z-only: a grid row per TPDO
    bench.node.nmt.send_command(0x02)
    time.sleep(0.05)
    assert bench.server.nodes[0].state == STOPPED
    bench.master.sync.transmit()
    assert not [m for m in bench.collect(0.2) if 0x180 <= m.arbitration_id < 0x580]
    bench.node.nmt.send_command(0x81)
    frames = bench.collect(0.2)
    assert any(m.arbitration_id == 0x701 and bytes(m.data) == b"\x00" for m in frames)
    assert bench.server.nodes[0].state == PRE_OPERATIONAL


def test_heartbeat_period_and_sdo_change(bench: Bench) -> None:
    bench.node.sdo[0x1017].raw = 50
    beats = [m.timestamp for m in bench.collect(0.6) if m.arbitration_id == 0x701]
    assert np.mean(np.diff(beats[1:])) == pytest.approx(0.050, rel=0.1)
    bench.node.sdo[0x1017].raw = 100
    bench.collect(0.05)
    beats = [m.timestamp for m in bench.collect(0.8) if m.arbitration_id == 0x701]
    assert np.mean(np.diff(beats)) == pytest.approx(0.100, rel=0.1)


def test_remap_to_status_by_cia301_sequence(bench: Bench) -> None:
    sdo = bench.node.sdo
    sdo[0x1800][1].raw = 0x80000181
    sdo[0x1A00][0].raw = 0
    sdo[0x1A00][1].raw = 0x20040108
    sdo[0x1A00][2].raw = 0x20040208
    with pytest.raises(SdoAbortedError) as err:
        sdo[0x1A00][3].raw = 0x20020120  # REAL32 R0: not mappable
    assert err.value.code == 0x06040041
    sdo[0x1A00][0].raw = 2
    sdo[0x1800][1].raw = 0x181
    bench.node.nmt.send_command(0x01)
    time.sleep(0.05)
    bench.master.sync.transmit()
    first = [m for m in bench.collect(0.2) if m.arbitration_id == 0x181]
    assert [bytes(m.data) for m in first] == [b"\x00\x00"]


def test_emcy_on_fault_and_recovery(bench: Bench) -> None:
    patch = bench.server.nodes[0]
    r = np.full((9, 1), 1000.0)
    r[4, 0] = np.inf
    patch.update(r)
    r[4, 0] = 1000.0
    patch.update(r)
    emcy = [bytes(m.data) for m in bench.collect(0.2) if m.arbitration_id == 0x81]
    assert emcy == [b"\x00\x50\x81\x04\x01\x00\x00\x00", b"\x00\x00\x00\x04\x00\x00\x00\x00"]
