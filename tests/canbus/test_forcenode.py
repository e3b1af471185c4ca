# mypy: disable-error-code="no-untyped-call"
from __future__ import annotations

from collections.abc import Iterator
from functools import cache

import canopen
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from canbus.device.nmt_slave import OPERATIONAL, PRE_OPERATIONAL, STOPPED
from canbus.master.forceframes import COMPLETE, NO_VALUE, forces_to_mN
from canbus.master.forcenode import ForceNode, force_node_cob_ids
from canbus.od import load_od
from skin.errors import BusError, ConfigError
from tests.support.rigs.devicebus import DeviceBus
from tests.support.rigs.waiting import wait_until


@cache
def _consumer() -> canopen.RemoteNode:
    """A canopen master's view of force node 70, its TPDO maps read from eds/skin-forces.eds."""
    node = canopen.Network().add_node(canopen.RemoteNode(70, load_od("skin-forces", 70)))
    node.tpdo.read(from_od=True)
    return node


@cache
def _force_node() -> ForceNode:
    """One node for every example (50 ms to build): its frames depend on its input only."""
    return ForceNode(70, 6, heartbeat_ms=0)


def _decode(frames: list[tuple[int, bytes]]) -> tuple[list[int], int]:
    """canopen's own PDO decoding: the 27 forces (mN) and 0x2005."""
    node = _consumer()
    maps = {m.cob_id: m for m in node.tpdo.values() if m.enabled}
    assert sorted(maps) == sorted(cob for cob, _ in frames)
    raw = {}
    for cob, payload in frames:
        maps[cob].on_message(cob, bytearray(payload), 0.0)
        raw.update({(v.index, v.subindex): v.raw for v in maps[cob]})
    return [raw[(0x2000, k)] for k in range(1, 28)], raw[(0x2005, 0)]


force_components = st.one_of(st.floats(-40.0, 40.0), st.sampled_from([np.nan, np.inf, -np.inf]))


@given(hnp.arrays(np.float64, (9, 3), elements=force_components),
       hnp.arrays(np.bool_, (9,)), st.booleans())
def test_forces_round_trip_through_canopen_pdo_decoding(
        force: np.ndarray, valid: np.ndarray, complete: bool) -> None:
    forces, bits = _decode(_force_node().frames(force, valid, complete))
    mN = np.rint(force * 1000.0)
    fits = np.isfinite(mN) & (np.abs(mN) <= 32767)
    bus_valid = fits.all(axis=1) & valid
    expected = np.where(bus_valid[:, None], np.nan_to_num(mN), NO_VALUE).astype(int).reshape(27)
    assert forces == expected.tolist()  # exact mN; 0x8000 x 3 where a taxel has no value
    assert bits == sum(1 << k for k in range(9) if bus_valid[k]) | (COMPLETE if complete else 0)


def test_values_beyond_integer16_are_no_value_never_clipped() -> None:
    force = np.zeros((9, 3))
    force[0] = (32.767, -32.767, 32.7675)  # the last rounds to 32768 mN: does not fit
    force[1] = (np.nan, 0.0, 0.0)
    force[2] = (32.767, -32.767, 32.767)
    mN, valid = forces_to_mN(force, np.ones(9, dtype=bool))
    assert mN[0].tolist() == mN[1].tolist() == [NO_VALUE] * 3  # the taxel has no value
    assert mN[2].tolist() == [32767, -32767, 32767]
    assert valid.tolist() == [False, False] + [True] * 7


def test_cob_ids_cover_every_transmitted_identifier() -> None:
    node = ForceNode(70, 6)
    expected = {0x1C6, 0x2C6, 0x3C6, 0x4C6, 0x246, 0x346, 0x446, 0x546, 0xC6, 0x746, 0x5C6}
    assert node.cob_ids() == force_node_cob_ids(70) == expected
    assert {cob for cob, _ in node.frames(np.zeros((9, 3)), np.ones(9, bool), True)} < expected
    # without a contact summary TPDO 8 (0x500 + ID) is invalid from power-on
    assert ForceNode(70, 6, contact=None).cob_ids() == expected - {0x546}


def test_eds_maps_valid_taxels_into_tpdo7_and_the_contact_into_tpdo8_event_driven() -> None:
    node = ForceNode(70, 6)
    tpdo7, tpdo8 = node.codec.layouts[-2:]
    assert tpdo7.number == 7 and tpdo7.size == 8
    assert [(e.index, e.subindex) for e in tpdo7.entries] == [
        (0x2000, 25), (0x2000, 26), (0x2000, 27), (0x2005, 0)]
    assert tpdo8.number == 8 and tpdo8.size == 8 and tpdo8.cob_id == 0x546
    assert [(e.index, e.subindex) for e in tpdo8.entries] == [
        (0x2008, 3), (0x2008, 7), (0x2008, 8), (0x2008, 11), (0x2008, 12)]
    assert {int(node.store.value(0x1800 + n, 2)) for n in range(8)} == {254}


def test_bad_arguments_are_config_errors() -> None:
    with pytest.raises(ConfigError, match="source_patch"):
        ForceNode(70, 0)
    with pytest.raises(ConfigError, match="heartbeat_ms"):
        ForceNode(70, 6, heartbeat_ms=70000)
    with pytest.raises(BusError, match="attached"):
        ForceNode(70, 6).start()


class Bench(DeviceBus):
    """A force node on the device side, a canopen master's view of it, and the spy."""

    def __init__(self, channel: str) -> None:
        super().__init__(channel)
        self.force = ForceNode(70, 6, heartbeat_ms=50)
        self.force.attach(self.device)
        self.remote = self.master.add_node(canopen.RemoteNode(70, load_od("skin-forces", 70)))
        self.remote.sdo.RESPONSE_TIMEOUT = 1.0

    def close(self) -> None:
        self.force.detach()
        super().close()


@pytest.fixture
def bench(request: pytest.FixtureRequest) -> Iterator[Bench]:
    with Bench(request.node.name) as b:
        yield b


def test_sdo_reads_the_last_published_sample(bench: Bench) -> None:
    sdo = bench.remote.sdo
    assert sdo[0x2001].raw == 6  # source patch
    assert sdo[0x2005].raw == 0 and sdo[0x2000][1].raw == NO_VALUE  # nothing published yet
    assert [sdo[0x1018][s].raw for s in (1, 2, 4)] == [0, 2, 70]  # vendor, product, serial
    force = np.zeros((9, 3))
    force[4] = (0.25, -0.5, 3.125)
    valid = np.ones(9, dtype=bool)
    valid[8] = False
    reason = np.zeros(9, dtype=np.uint8)
    reason[8] = 8
    bench.force.frames(force, valid, True, reason=reason)
    assert [sdo[0x2000][13 + k].raw for k in range(3)] == [250, -500, 3125]
    assert sdo[0x2000][25].raw == NO_VALUE
    assert sdo[0x2005].raw == 0x80FF
    assert sdo[0x2004][9].raw == 8 and sdo[0x2004][1].raw == 0
    sdo[0x2001].raw = 7  # rw: a master may re-label the source
    assert sdo[0x2001].raw == 7


def test_an_invalid_taxel_carries_no_value_in_all_three_components_on_the_bus(
        bench: Bench) -> None:
    """docs/dataplane.md: a taxel whose valid bit is clear is 0x8000 in x, y and z, whether
    the decoder masked it or one of its components does not fit INTEGER16."""
    bench.force.start()
    force = np.full((9, 3), 0.5)
    force[1] = (2.208, -3.28, 40.0)  # z beyond +-32.767 N: the taxel cannot be sent
    force[2] = (0.1, 0.2, np.nan)
    valid = np.ones(9, dtype=bool)
    valid[3] = False  # the decoder's verdict, its forces finite
    for cob, payload in bench.force.frames(force, valid, True):
        bench.device.send_message(cob, payload)
    tpdos = bench.force.cob_ids() - {0x746, 0xC6, 0x5C6}
    got = bench.collect_until(lambda seen: tpdos <= {m.arbitration_id for m in seen},
                              what="every TPDO of the sample")
    forces, bits = _decode([(m.arbitration_id, bytes(m.data)) for m in got
                            if m.arbitration_id in tpdos])
    by_taxel = np.array(forces).reshape(9, 3)
    for taxel in (1, 2, 3):
        assert by_taxel[taxel].tolist() == [NO_VALUE] * 3 and not bits & (1 << taxel)
    assert by_taxel[0].tolist() == [500] * 3 and bits & 1
    assert [bench.remote.sdo[0x2000][4 + k].raw for k in range(3)] == [NO_VALUE] * 3


def test_boot_heartbeat_start_and_nmt_stop(bench: Bench) -> None:
    assert bench.force.state == PRE_OPERATIONAL and not bench.force.transmitting
    bench.force.start()
    assert bench.force.state == OPERATIONAL and bench.force.transmitting
    beats = [m for m in bench.collect(0.3) if m.arbitration_id == 0x746]
    assert len(beats) >= 2 and bytes(beats[-1].data) == bytes([OPERATIONAL])
    bench.remote.nmt.send_command(0x02)  # another master stops the node
    wait_until(lambda: bench.force.state == STOPPED, what="the force node stopped")
    assert not bench.force.transmitting
    beats = [m for m in bench.collect(0.15) if m.arbitration_id == 0x746]
    assert beats and bytes(beats[-1].data) == bytes([STOPPED])
    bench.remote.nmt.send_command(0x81)  # reset node: boot-up, pre-operational
    after = [bytes(m.data) for m in bench.collect(0.1) if m.arbitration_id == 0x746]
    assert b"\x00" in after and bench.force.state == PRE_OPERATIONAL


def test_remap_by_sdo_changes_cob_ids_and_frames(bench: Bench) -> None:
    sdo = bench.remote.sdo
    sdo[0x1800][1].raw = 0x800001C6  # invalidate TPDO 1, then move it
    sdo[0x1800][1].raw = 0x800001D0
    sdo[0x1800][1].raw = 0x1D0
    assert 0x1D0 in bench.force.cob_ids() and 0x1C6 not in bench.force.cob_ids()
    frames = bench.force.frames(np.ones((9, 3)), np.ones(9, dtype=bool), True)
    assert frames[0] == (0x1D0, (1000).to_bytes(2, "little") * 4)
