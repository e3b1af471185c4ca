"""The CiA 301 objects a master reads or sets on a sensor node (0x1003, 0x1005, 0x1008..0x100A,
0x1019, 0x1029) in both nodes, and two SDO server details: a block upload initiate aborts
with 0x05040001, a segmented download announcing more than the object holds aborts at
initiate with 0x06070012 (byte traces; hypothesis over announced sizes)."""

from __future__ import annotations

import struct
from collections.abc import Iterator

import can
import canopen
import numpy as np
import pytest
from canopen.sdo.exceptions import SdoAbortedError
from hypothesis import given, settings
from hypothesis import strategies as st

from canbus.device.nmt_slave import OPERATIONAL, PRE_OPERATIONAL, STOPPED
from canbus.device.object_store import ObjectStore
from canbus.device.patch_server import PatchServer
from canbus.master.forcenode import ForceNode
from canbus.od import load_od
from tests.support.rigs.devicebus import DeviceBus
from tests.support.rigs.host import Rest
from tests.support.rigs.waiting import wait_until


class Rig(DeviceBus):
    """Patch 1 on the device side, seen from the master through the EDS."""

    def __init__(self, channel: str) -> None:
        super().__init__(channel)
        self.server = PatchServer(self.device, Rest(1))
        self.server.start()
        self.patch = self.server.nodes[0]
        self.node = self.master.add_node(canopen.RemoteNode(1, load_od("skin-patch", 1)))
        self.node.sdo.RESPONSE_TIMEOUT = 2.0

    def sdo_exchange(self, request: bytes) -> bytes:
        """Send one SDO request frame; the server's response frame."""
        self.drain()
        self.spy.send(can.Message(arbitration_id=0x601, data=request, is_extended_id=False))
        answer = self.collect_until(lambda got: bool(got) and got[-1].arbitration_id == 0x581,
                                    what="an SDO response")[-1]
        return bytes(answer.data)

    def start(self) -> None:
        """NMT start to the patch; returns once it is operational."""
        self.node.nmt.send_command(0x01)
        wait_until(lambda: self.patch.state == OPERATIONAL, what="the patch operational")

    def close(self) -> None:
        self.server.stop()
        super().close()


@pytest.fixture
def rig(request: pytest.FixtureRequest) -> Iterator[Rig]:
    with Rig(request.node.name) as r:
        yield r


def _abort(index: int, sub: int, code: int) -> bytes:
    return struct.pack("<BHBI", 0x80, index, sub, code)


def test_block_upload_initiate_aborts_with_command_unknown(rig: Rig) -> None:
    request = struct.pack("<BHBBB2x", 0xA4, 0x1018, 1, 127, 0)  # ccs 5, block size 127
    assert rig.sdo_exchange(request) == _abort(0x1018, 1, 0x0504_0001)
    request = struct.pack("<BHBI", 0xC6, 0x1017, 0, 2)  # block download initiate
    assert rig.sdo_exchange(request) == _abort(0x1017, 0, 0x0504_0001)


def test_a_segmented_download_of_4_gib_into_unsigned16_aborts_at_initiate(rig: Rig) -> None:
    request = struct.pack("<BHBI", 0x21, 0x1017, 0, 0xFFFF_FFFF)
    assert rig.sdo_exchange(request) == _abort(0x1017, 0, 0x0607_0012)


class _Capture:
    def __init__(self) -> None:
        self.sent: list[bytes] = []

    def send_message(self, cob_id: int, data: bytes) -> None:
        self.sent.append(bytes(data))


_STORE = ObjectStore(1, load_od("skin-patch", 1))


@settings(max_examples=60)
@given(st.sampled_from([(0x1017, 0, 2), (0x1800, 2, 1), (0x1800, 1, 4), (0x2002, 3, 4),
                        (0x1019, 0, 1)]),
       st.integers(0, 0xFFFF_FFFF))
def test_a_segmented_download_is_judged_by_its_announced_size(
        target: tuple[int, int, int], announced: int) -> None:
    index, sub, size = target
    capture = _Capture()
    _STORE.sdo.network = capture
    _STORE.sdo.on_request(0x601, struct.pack("<BHBI", 0x21, index, sub, announced), 0.0)
    if announced > size:
        assert capture.sent == [_abort(index, sub, 0x0607_0012)]
    elif announced < size:
        assert capture.sent == [_abort(index, sub, 0x0607_0013)]
    else:
        assert capture.sent == [struct.pack("<BHB4x", 0x60, index, sub)]  # segments next
        _STORE.sdo.on_request(0x601, _abort(index, sub, 0x0504_0000), 0.0)


def test_the_error_history_keeps_each_fault_newest_first(rig: Rig) -> None:
    sdo = rig.node.sdo
    assert sdo.upload(0x1003, 0) == b"\x00"
    with pytest.raises(SdoAbortedError) as err:
        sdo.upload(0x1003, 1)  # no entry yet
    assert err.value.code == 0x0800_0024
    r = np.tile(rig.patch.constants.nominal_resistance_ohm, (9, 1))
    r[4, 0], r[7, 1] = np.inf, 0.0  # taxel 4 open, then taxel 7 short
    rig.patch.update(r)
    assert sdo.upload(0x1003, 0) == b"\x02"
    entries = [struct.unpack("<I", sdo.upload(0x1003, s))[0] for s in (1, 2)]
    status = rig.patch.faults.status
    assert entries == [0x5000 | ((7 | int(status[7]) << 8) << 16),
                       0x5000 | ((4 | int(status[4]) << 8) << 16)]
    with pytest.raises(SdoAbortedError) as err:
        sdo.download(0x1003, 0, b"\x01")  # only 0 may be written
    assert err.value.code == 0x0609_0030
    sdo.download(0x1003, 0, b"\x00")
    assert sdo.upload(0x1003, 0) == b"\x00"


@pytest.mark.parametrize(("behaviour", "after"), [(0, PRE_OPERATIONAL), (1, OPERATIONAL),
                                                  (2, STOPPED)])
def test_a_communication_error_follows_the_error_behaviour(rig: Rig, behaviour: int,
                                                           after: int) -> None:
    rig.node.sdo.download(0x1029, 1, bytes([behaviour]))
    with pytest.raises(SdoAbortedError) as err:
        rig.node.sdo.download(0x1029, 1, b"\x03")
    assert err.value.code == 0x0609_0031  # HighLimit 2
    rig.start()
    rig.patch.communication_error()
    assert rig.patch.state == after
    assert rig.node.sdo.upload(0x1003, 1)[:2] == b"\x00\x81"  # 0x8100 communication


def test_the_sync_cob_id_is_writable_and_followed(rig: Rig) -> None:
    sdo = rig.node.sdo
    for bad in (0x4000_0080, 0x2000_0080):  # generate SYNC; 29-bit
        with pytest.raises(SdoAbortedError) as err:
            sdo.download(0x1005, 0, struct.pack("<I", bad))
        assert err.value.code == 0x0609_0030
    sdo.download(0x1005, 0, struct.pack("<I", 0x81))
    rig.start()
    rig.spy.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
    rig.spy.send(can.Message(arbitration_id=0x081, data=b"", is_extended_id=False))
    first = rig.wait_for(lambda m: m.arbitration_id == 0x181, what="TPDO 1")
    assert rig.server.sync_count == 1  # the SYNC on 0x080 went unanswered
    assert len(first.data) == 8


def test_sync_overflow_value_and_names(rig: Rig) -> None:
    sdo = rig.node.sdo
    for bad in (1, 241, 255):
        with pytest.raises(SdoAbortedError) as err:
            sdo.download(0x1019, 0, bytes([bad]))
        assert err.value.code == 0x0609_0030
    sdo.download(0x1019, 0, b"\x10")
    assert sdo.upload(0x1019, 0) == b"\x10"
    assert sdo[0x1008].raw == "canskin tactile patch"
    assert sdo[0x1009].raw == "1.0" and sdo[0x100A].raw == "0.1.0"


def test_the_force_node_has_the_same_objects() -> None:
    node = ForceNode(65, 1)
    assert node.store.value(0x1008) == "canskin force node"
    node.store.set_data(0x1005, 0, struct.pack("<I", 0x90), check_writable=True)
    assert node.sync_cob_id() == 0x90
    for index in (0x1003, 0x1010, 0x1011, 0x1019, 0x1029):
        assert index in node.store.object_dictionary
