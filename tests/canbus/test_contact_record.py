"""The contact summary on the wire: what canopen's own PDO decoding reads of TPDO 8 (and of
any remap) is the API's summary in the objects' units; no value is never a number."""

from __future__ import annotations

import canopen
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from canbus import contact_record
from canbus.master.contact import PatchContact, summarize_batch
from canbus.master.forceframes import batch_frames
from canbus.master.forcenode import ForceNode
from canbus.od import load_od
from skin.contact import ContactParams, PatchGeometry

NO_VALUE = -0x8000
forces = arrays(np.float64, (9, 3), elements=st.floats(-40.0, 40.0))


def _canopen_map(node_id: int, number: int) -> canopen.pdo.base.PdoMap:
    network = canopen.Network()
    node = canopen.RemoteNode(node_id, load_od("skin-forces", node_id))
    network.add_node(node)
    node.tpdo.read(from_od=True)
    return node.tpdo[number]


TPDO8 = _canopen_map(65, 8)


def _counts(value: float, scale: float, has: bool) -> int:
    counts = int(np.rint(value * round(1 / scale)))
    return counts if has and abs(counts) <= 0x7FFF else NO_VALUE


@settings(max_examples=150, deadline=None)
@given(force=forces, valid=arrays(np.bool_, 9))
def test_tpdo8_read_by_canopen_is_the_api_summary(force: np.ndarray, valid: np.ndarray) -> None:
    node = ForceNode(65, 1)
    f = np.where(valid[:, None], force, 0.0)
    frames = dict(node.frames(f, valid, True))
    contact = summarize_batch([PatchContact()], f[None], valid[None])  # the same judge, anew
    summary = contact.row(0)
    TPDO8.on_message(0x541, bytearray(frames[0x541]), 0.0)
    got = {v.subindex: v.raw for v in TPDO8.map}
    assert got[3] == _counts(summary.force_N[2], 0.01, summary.valid_taxels > 0)
    assert got[7] == _counts(summary.cop_m[0], 1e-5, summary.cop_defined)
    assert got[8] == _counts(summary.cop_m[1], 1e-5, summary.cop_defined)
    flags = (summary.in_contact, summary.onset, summary.release, summary.near_slip,
             summary.slipping, summary.slip_onset, summary.partial, summary.unknown)
    assert got[11] == sum(1 << k for k, on in enumerate(flags) if on)
    assert got[12] == summary.taxels_in_contact == int((valid & (force[:, 2] > 0.12)).sum())
    assert summary.in_contact == (summary.force_N[2] >= 0.3)  # a first sample: onset rule


def _half_count(scale: float) -> float:
    """Half a count of ``scale``, and the last bit the decoded value (count x scale) may
    round by: a value half-way between two counts is at most this far from either."""
    return 0.5 * scale * (1 + 1e-12)


@settings(max_examples=60, deadline=None)
@given(force=forces, valid=arrays(np.bool_, 9), angle=st.floats(-180, 180))
def test_every_sub_index_decodes_to_the_summary_in_si_units(force: np.ndarray,
                                                            valid: np.ndarray,
                                                            angle: float) -> None:
    judge = PatchContact(PatchGeometry(0.015, (0.2, -0.1), angle), ContactParams(friction=0.4))
    batch = summarize_batch([judge], np.where(valid[:, None], force, 0.0)[None], valid[None])
    subs = list(range(1, contact_record.SUBS + 1))
    values = dict(zip(subs, contact_record.encode(batch, subs)[0].tolist(), strict=True))
    bus = contact_record.decode(values)
    c = batch.row(0)
    known = c.valid_taxels > 0
    for k in range(3):
        fits = abs(np.rint(c.force_N[k] * 100)) <= 0x7FFF
        expected = c.force_N[k] if known and fits else None
        assert bus.force_N[k] == (None if expected is None else pytest.approx(
            expected, abs=_half_count(0.01)))
    if c.cop_defined:
        assert bus.cop_m == pytest.approx(tuple(c.cop_m), abs=_half_count(1e-5))
        assert bus.cop_placed_m == pytest.approx(tuple(c.cop_placed_m), abs=_half_count(1e-4))
        assert bus.tangential_ratio is None or bus.tangential_ratio == pytest.approx(
            c.tangential_ratio, abs=_half_count(1e-3))
    else:
        assert bus.cop_m is None and bus.cop_placed_m is None and bus.tangential_ratio is None
    assert bus.taxels_in_contact == c.taxels_in_contact
    assert bus.contact_taxels == sum(1 << k for k in range(9) if c.contact_taxels[k])
    assert bus.slip_taxels == sum(1 << k for k in range(9) if c.taxel_slip[k])
    assert bus.in_contact == c.in_contact and bus.slipping == c.slipping
    assert bus.flag(contact_record.UNKNOWN) == c.unknown


def test_no_summary_and_a_summary_too_big_for_its_type() -> None:
    assert contact_record.no_summary([3, 7, 11, 12, 15], 2).tolist() == [
        [NO_VALUE, NO_VALUE, contact_record.UNKNOWN, 0, 0xFFFF]] * 2
    force = np.zeros((1, 9, 3))
    force[0, :, 2] = 40.0  # 360 N over the patch: beyond 327.67 N, no value, not clipped
    batch = summarize_batch([PatchContact()], force, np.ones((1, 9), dtype=bool))
    fz, cop_x, state = contact_record.encode(batch, [3, 7, 11])[0].tolist()
    assert fz == NO_VALUE and cop_x == 0 and state & contact_record.IN_CONTACT
    with pytest.raises(ValueError, match="no sub-index 16"):
        contact_record.encode(batch, [16])
    assert contact_record.state_text(0) == "free"
    assert contact_record.state_text(0x19) == "contact,near-slip,slipping"


def test_a_node_without_a_judge_answers_no_summary_and_packs_it_when_mapped() -> None:
    plain = ForceNode(66, 2, contact=None)
    assert plain.store.value(0x2008, 3) == NO_VALUE
    assert plain.store.value(0x2008, 11) == contact_record.UNKNOWN
    judged = ForceNode(65, 1)
    force = np.zeros((2, 9, 3))
    force[:, 4, 2] = 1.0
    valid = np.ones((2, 9), dtype=bool)
    batch = summarize_batch([judged.contact, PatchContact()], force, valid)  # type: ignore[list-item]
    # the plain node's TPDO 8 is invalid; were it mapped, it would say: no summary
    frames = batch_frames([judged, plain], force, valid, np.ones(2, bool), contact=batch)
    assert [c for c, _ in frames[0]][-1] == 0x541 and 0x542 not in [c for c, _ in frames[1]]
    assert judged.store.value(0x2008, 3) == 100 and judged.store.value(0x2008, 12) == 1


def test_the_sniffer_names_the_contact_pdo_and_its_values() -> None:
    import can

    from canbus.tools.attribution import Attribution, KnownNode
    from canbus.tools.pdo_dictionary import Dictionary
    from canbus.tools.services import ServiceDecoder

    node = ForceNode(65, 1)
    force = np.zeros((9, 3))
    force[5] = (0.2, 0.1, 2.0)
    force[4] = (0.0, 0.0, 1.0)
    frames = dict(node.frames(force, np.ones(9, bool), True))
    told = Attribution(Dictionary(), [KnownNode(65, "skin-forces")])  # as --config tells it
    decoded = ServiceDecoder(attribution=told).decode(
        can.Message(arbitration_id=0x541, data=frames[0x541], is_extended_id=False))
    assert decoded.label == "TPDO8 contact"
    assert decoded.text == ("Fz=+3.00 N CoPx=+10.00 mm CoPy=+0.00 mm state=contact,onset "
                            "taxels=2")


def test_a_can_fd_sample_carries_the_contact_in_its_64_bytes() -> None:
    import struct

    from canbus.master.forcenode import map_fd

    node = ForceNode(65, 1, heartbeat_ms=0)
    node.tpdo.max_bytes = 64  # a CAN FD bus (what attach() sets from the bus)
    map_fd(node)
    force = np.zeros((9, 3))
    force[8] = (0.0, 0.0, 2.5)
    ((cob, payload),) = node.frames(force, np.ones(9, bool), True, answered=17)
    assert cob == 0x1C1 and len(payload) == 64
    fz, x, y, state = struct.unpack_from("<hhhB", payload, 57)
    assert payload[56] == 17 and fz == 250 and (x, y) == (1500, 1500)
    assert state == contact_record.IN_CONTACT | contact_record.ONSET
    plain = ForceNode(66, 2, heartbeat_ms=0, contact=None)
    plain.tpdo.max_bytes = 64
    map_fd(plain)
    ((_, payload),) = plain.frames(force, np.ones(9, bool), True)
    assert struct.unpack_from("<hhhB", payload, 57) == (NO_VALUE, NO_VALUE, NO_VALUE,
                                                        contact_record.UNKNOWN)
