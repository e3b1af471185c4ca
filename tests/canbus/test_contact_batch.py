"""The host's batch summary (canbus.master.contact: many patches at once into buffers made
once per batch composition, the state by table lookups, the default contact PDO's figures
counted with the forces) gives, bit for bit, what the plain per-patch path gives
(skin.contact.summarize, then skin.contact_state.track over each patch's own samples in
order): every figure, every state bit, every byte on the bus."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from canbus import contact_record
from canbus.master.contact import (
    ContactSummarizer,
    PatchContact,
    summarize_batch,
    summarize_nodes,
)
from canbus.master.forceframes import batch_frames, forces_to_mN
from canbus.master.forcenode import CONTACT_TPDO, ForceNode
from canbus.pdo_codec import COB_ID_INVALID, TPDO_COMM, TPDO_MAP
from skin.contact import ContactParams, PatchGeometry, summarize
from skin.contact_state import ContactBatch, track

ALL_SUBS = list(range(1, contact_record.SUBS + 1))
FIGURES = ("force_N", "torque_Nm", "cop_m", "cop_placed_m", "force_placed_N",
           "tangential_ratio", "contact_area_m2", "cop_defined", "contact_taxels",
           "taxels_in_contact", "valid_taxels", "taxel_slip", "taxel_near_slip", "near_slip",
           "slip")
STATE = ("partial", "unknown", "in_contact", "onset", "release", "near_slip", "slipping",
         "slip_onset")


@st.composite
def judges(draw: st.DrawFn) -> PatchContact:
    release = draw(st.floats(0.05, 1.0))
    params = ContactParams(taxel_contact_N=draw(st.floats(0.01, 0.5)),
                           onset_N=release + draw(st.floats(0.0, 1.0)), release_N=release,
                           friction=draw(st.floats(0.1, 1.5)),
                           near_slip_margin=draw(st.floats(0.0, 0.9)))
    geometry = PatchGeometry(draw(st.floats(0.002, 0.05)),
                             (draw(st.floats(-1.0, 1.0)), draw(st.floats(-1.0, 1.0))),
                             draw(st.floats(-180.0, 180.0)))
    return PatchContact(geometry, params)


@dataclass
class Stream:
    """Rows of a batch (a decoder's forces: finite, 0 where invalid) and whose they are."""

    judges: list[PatchContact]
    owner: list[int]  # row i is a sample of judges[owner[i]]
    force: np.ndarray
    valid: np.ndarray

    def rows_of(self, patch: int) -> list[int]:
        return [i for i, o in enumerate(self.owner) if o == patch]


@st.composite
def streams(draw: st.DrawFn, max_rows: int = 24) -> Stream:
    patches = draw(st.lists(judges(), min_size=1, max_size=4))
    n = draw(st.integers(1, max_rows))
    owner = draw(st.lists(st.integers(0, len(patches) - 1), min_size=n, max_size=n))
    # presses around the thresholds, shear around the friction cone, some far beyond
    element = st.one_of(st.floats(-2.0, 2.0), st.floats(-400.0, 400.0),
                        st.sampled_from([0.0, 0.3, 0.2, 0.12, 1e-300]))
    force = draw(arrays(np.float64, (n, 9, 3), elements=element))
    valid = draw(arrays(np.bool_, (n, 9)))
    force[~valid] = 0.0
    return Stream(patches, owner, force, valid)


def _plain(stream: Stream) -> tuple[list[tuple[ContactBatch, int]], list[int]]:
    """Each row's summary the plain way (each patch's rows alone, in order, from state 0)
    and each patch's state after its last row."""
    out: list[tuple[ContactBatch, int]] = [None] * len(stream.owner)  # type: ignore[list-item]
    finals = []
    for p, judge in enumerate(stream.judges):
        rows = stream.rows_of(p)
        instant = summarize(stream.force[rows], stream.valid[rows], geometry=judge.geometry,
                            params=judge.params)
        final, batch = track(instant, judge.params)
        finals.append(final)
        for k, i in enumerate(rows):
            out[i] = (batch, k)
    return out, finals


def _same(fast: ContactBatch, i: int, plain: ContactBatch, k: int) -> None:
    for name in FIGURES:
        np.testing.assert_array_equal(getattr(fast.instant, name)[i],
                                      getattr(plain.instant, name)[k], err_msg=name)
    a, b = fast.row(i), plain.row(k)
    for name in STATE:
        assert getattr(a, name) == getattr(b, name), name
    assert int(fast.state_byte[i]) == int(plain.state_byte[k])
    np.testing.assert_array_equal(contact_record.encode(fast, ALL_SUBS)[i],
                                  contact_record.encode(plain, ALL_SUBS)[k])


@settings(max_examples=200, deadline=None)
@given(stream=streams())
def test_the_batch_path_gives_the_plain_path_s_summary_bit_for_bit(stream: Stream) -> None:
    batch = summarize_batch([stream.judges[o] for o in stream.owner], stream.force,
                            stream.valid)
    plain, finals = _plain(stream)
    for i, (one, k) in enumerate(plain):
        _same(batch, i, one, k)
    assert [j.state for j in stream.judges] == finals


@settings(max_examples=100, deadline=None)
@given(stream=streams(), data=st.data())
def test_a_sample_s_summary_is_the_same_bits_in_any_batch(stream: Stream,
                                                          data: st.DataObject) -> None:
    """Among more or fewer others, first or last: one patch's rows summarised with
    different neighbours give the same figures (the sums' order does not follow the batch)."""
    judge = stream.judges[0]
    alone = summarize_batch([judge] * len(stream.owner), stream.force, stream.valid)
    judge.reset()
    extra = data.draw(st.integers(0, 40))
    noise = np.random.default_rng(extra).normal(0.0, 3.0, (extra, 9, 3))
    force = np.concatenate([noise, stream.force])
    valid = np.concatenate([np.ones((extra, 9), dtype=bool), stream.valid])
    among = summarize_batch([PatchContact()] * extra + [judge] * len(stream.owner), force,
                            valid)
    np.testing.assert_array_equal(among.instant.sums[:, extra:], alone.instant.sums)
    np.testing.assert_array_equal(among.state_byte[extra:], alone.state_byte)


@settings(max_examples=100, deadline=None)
@given(stream=streams())
def test_the_batch_path_is_the_checked_path_bit_for_bit(stream: Stream) -> None:
    """The same rows through the checking path (``decoded=False``: finiteness and overflow
    checked): every figure and byte identical."""
    rows = [stream.judges[o] for o in stream.owner]
    fast = summarize_batch(rows, stream.force, stream.valid)
    for judge in stream.judges:
        judge.reset()
    checked = summarize_batch(rows, stream.force, stream.valid, decoded=False)
    for name in ("sums", *FIGURES):
        np.testing.assert_array_equal(getattr(fast.instant, name),
                                      getattr(checked.instant, name), err_msg=name)
    np.testing.assert_array_equal(fast.state_byte, checked.state_byte)
    np.testing.assert_array_equal(contact_record.encode(fast, ALL_SUBS),
                                  contact_record.encode(checked, ALL_SUBS))


def _nodes(stream: Stream, judged: list[bool]) -> list[ForceNode]:
    return [ForceNode(65 + i, 1 + i, contact=PatchContact(stream.judges[0].geometry,
                                                          stream.judges[0].params)
                      if judged[i] else None) for i in range(len(stream.owner))]


@settings(max_examples=60, deadline=None)
@given(stream=streams(), judged=st.lists(st.booleans(), min_size=24, max_size=24))
def test_force_nodes_with_and_without_a_judge_in_one_batch(stream: Stream,
                                                           judged: list[bool]) -> None:
    """A batch of force nodes, some without a contact judge: those rows get no summary (in
    the API and on the bus) and the others the plain path's, whatever the mix."""
    n = len(stream.owner)
    nodes = _nodes(stream, judged)
    batch = summarize_nodes(nodes, stream.force, stream.valid)
    if not any(judged[:n]):
        assert batch is None
        return
    assert batch is not None
    frames = batch_frames(nodes, stream.force, stream.valid, np.ones(n, dtype=bool),
                          contact=batch)
    for i in range(n):
        alone = Stream([stream.judges[0]], [0], stream.force[i:i + 1], stream.valid[i:i + 1])
        (plain, k), = _plain(alone)[0]
        if judged[i]:
            _same(batch, i, plain, k)
            tpdo8 = frames[i][-1][1]
            expected = contact_record.encode(plain, contact_record.DEFAULT_TPDO)[k]
            assert [int.from_bytes(tpdo8[a:b], "little", signed=True) for a, b in
                    ((0, 2), (2, 4), (4, 6))] == expected[:3].tolist()
            assert list(tpdo8[6:]) == expected[3:].tolist()
        else:
            assert len(frames[i]) == 7  # TPDO 8 invalid without a judge


def _remap_tpdo8(node: ForceNode, subs: list[int]) -> None:
    """Map the node's TPDO 8 to 0x2008 ``subs`` (CiA 301's sequence, as a master's SDO)."""
    comm, mapping = TPDO_COMM + CONTACT_TPDO - 1, TPDO_MAP + CONTACT_TPDO - 1
    cob = int(node.store.value(comm, 1))
    with node.lock:
        node.store.set_data(comm, 1, (cob | COB_ID_INVALID).to_bytes(4, "little"))
        node.store.set_data(mapping, 0, b"\x00")
        for k, sub in enumerate(subs, start=1):
            bits = 8 if sub in (contact_record.STATE, contact_record.COUNT) else 16
            raw = contact_record.CONTACT << 16 | sub << 8 | bits
            node.store.set_data(mapping, k, raw.to_bytes(4, "little"))
        node.store.set_data(mapping, 0, bytes([len(subs)]))
        node.store.set_data(comm, 1, (cob & ~COB_ID_INVALID).to_bytes(4, "little"))


@settings(max_examples=60, deadline=None)
@given(stream=streams(max_rows=8), subs=st.lists(st.sampled_from(ALL_SUBS), min_size=1,
                                                  max_size=4, unique=True))
def test_every_mapping_sends_what_the_summary_encodes(stream: Stream, subs: list[int]) -> None:
    """The host counts the default PDO's figures with the forces; a node remapped to any
    sub-indices, beside nodes mapped by default, sends what :func:`encode` gives, and every
    frame is the one the summary's own encoding gives (the forces :func:`forces_to_mN`'s)."""
    n = len(stream.owner)
    nodes = _nodes(stream, [True] * n)
    _remap_tpdo8(nodes[0], subs)
    batch = summarize_nodes(nodes, stream.force, stream.valid)
    assert batch is not None
    frames = batch_frames(nodes, stream.force, stream.valid, np.ones(n, dtype=bool),
                          contact=batch)
    assert batch.take_published() is None  # the host's figures are taken once
    values = contact_record.encode(batch, subs)[0].tolist()
    sizes = [1 if s in (contact_record.STATE, contact_record.COUNT) else 2 for s in subs]
    payload, at, got = frames[0][-1][1], 0, []
    for sub, size in zip(subs, sizes, strict=True):
        got.append(int.from_bytes(payload[at:at + size], "little",
                                  signed=sub <= 10))
        at += size
    assert got == values
    # again, from the summary alone (its own encoding): the same bytes
    assert batch_frames(nodes, stream.force, stream.valid, np.ones(n, dtype=bool),
                        contact=batch) == frames
    mN, _ = forces_to_mN(stream.force, stream.valid)
    for i, node in enumerate(nodes):
        assert [int(node.store.value(0x2000, s)) for s in range(1, 28)] == \
            mN[i].reshape(27).tolist()


@dataclass
class Holder:
    """A force node as the summarizer reads it: its contact judge."""

    contact: PatchContact | None


def _twin(judge: PatchContact | None) -> PatchContact | None:
    if judge is None:
        return None
    twin = PatchContact(judge.geometry, judge.params)
    twin.state = judge.state
    return twin


@settings(max_examples=60, deadline=None)
@given(stream=streams(max_rows=8), edits=st.lists(st.tuples(
    st.integers(0, 7), st.sampled_from(["params", "geometry", "replace", "remove"]),
    judges()), min_size=1, max_size=6))
def test_a_summarizer_s_kept_compositions_follow_their_judges(
        stream: Stream, edits: list[tuple[int, str, PatchContact]]) -> None:
    """Batch after batch, a summarizer that keeps its compositions gives what one made anew
    gives, whatever changed in between: a judge's thresholds or geometry, a node's judge
    replaced or taken away."""
    kept = ContactSummarizer()
    nodes = [Holder(stream.judges[o]) for o in stream.owner]
    twins = {id(j): _twin(j) for j in stream.judges}
    fresh = [Holder(twins[id(node.contact)]) for node in nodes]
    n = len(nodes)
    for row, what, other in [(0, "none", PatchContact()), *edits]:
        node, twin = nodes[row % n], fresh[row % n]
        if what in ("params", "geometry") and node.contact is not None:
            assert twin.contact is not None
            setattr(node.contact, what, getattr(other, what))
            setattr(twin.contact, what, getattr(other, what))
        elif what == "replace":
            node.contact, twin.contact = other, _twin(other)
        elif what == "remove":
            node.contact = twin.contact = None
        ours = kept.nodes(nodes, stream.force, stream.valid)
        anew = summarize_nodes(fresh, stream.force, stream.valid)
        assert (ours is None) == (anew is None)
        if ours is None or anew is None:
            continue
        np.testing.assert_array_equal(ours.instant.sums, anew.instant.sums)
        np.testing.assert_array_equal(ours.state_byte, anew.state_byte)
        assert [n.contact.state for n in nodes if n.contact is not None] == \
            [n.contact.state for n in fresh if n.contact is not None]
