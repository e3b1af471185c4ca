"""The force sample's bytes (docs/zenoh.md): round trips, the documented offsets, later
extensions skipped, and hostile payloads refused with a SchemaError and nothing else."""

from __future__ import annotations

import struct

import msgpack
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from canbus.master.dataplane import ForceFrame
from canbus.zenoh import schema
from canbus.zenoh.schema import SchemaError, decode_forces, encode_forces

names = st.text(st.characters(blacklist_categories=("Cs",)), max_size=20).filter(
    lambda s: len(s.encode()) <= 255)


@st.composite
def frames(draw: st.DrawFn) -> ForceFrame:
    taxels = draw(st.integers(1, 16))
    axes = draw(st.integers(1, 3))
    reason = draw(arrays(np.uint8, taxels, elements=st.integers(0, 255)))
    valid = reason == 0
    force = draw(arrays(np.float64, (taxels, axes),
                        elements=st.floats(allow_nan=False, allow_infinity=False)))
    force[~valid] = 0.0
    return ForceFrame(draw(st.integers(1, 127)), draw(st.integers(1, 127)),
                      draw(st.integers(0, 2**64 - 1)), draw(st.integers(0, 255)),
                      draw(st.floats(allow_nan=False)), force, valid, reason,
                      draw(st.booleans()), draw(st.booleans()))


@given(frames(), names, names, st.floats(allow_nan=False), st.floats(allow_nan=False),
       st.lists(st.tuples(st.integers(0, 255), st.binary(max_size=40)), max_size=3))
def test_every_frame_comes_back_as_it_went(frame: ForceFrame, host: str, bus: str,
                                           published: float, sent: float,
                                           extensions: list[tuple[int, bytes]]) -> None:
    payload = encode_forces(frame, host.encode(), bus.encode(), published, sent,
                            tuple(extensions))
    back = decode_forces(payload, 1.5)
    out = back.frame
    assert (out.patch, out.force_node, out.cycle, out.sync_counter, out.complete,
            out.published) == (frame.patch, frame.force_node, frame.cycle, frame.sync_counter,
                               frame.complete, frame.published)
    assert struct.pack("<d", out.timestamp) == struct.pack("<d", frame.timestamp)
    assert out.force_N.tobytes() == frame.force_N.tobytes()  # -0.0 and all
    assert np.array_equal(out.valid, frame.valid) and np.array_equal(out.reason, frame.reason)
    assert (back.host, back.bus, back.received) == (host, bus, 1.5)
    assert struct.pack("<dd", back.published, back.sent) == struct.pack("<dd", published, sent)
    assert back.extensions == tuple(extensions)


def _typical() -> ForceFrame:
    force = np.arange(27, dtype=np.float64).reshape(9, 3) / 10
    reason = np.zeros(9, np.uint8)
    reason[4] = 8
    force[4] = 0.0
    return ForceFrame(3, 67, 1000, 17, 1.7e9, force, reason == 0, reason, False, True)


def test_the_bytes_are_where_the_docs_say() -> None:
    payload = encode_forces(_typical(), b"arm", b"can0", 1.7e9 + 0.001, 1.7e9 + 0.002)
    assert payload[:8] == bytes([1, 0b10, 3, 67, 17, 9, 3, 0])
    assert struct.unpack_from("<Qddd", payload, 8) == (1000, 1.7e9, 1.7e9 + 0.001,
                                                       1.7e9 + 0.002)
    assert struct.unpack_from("<27d", payload, 40)[:3] == (0.0, 0.1, 0.2)
    assert payload[256:265] == bytes([0, 0, 0, 0, 8, 0, 0, 0, 0])
    assert struct.unpack_from("<H", payload, 265) == (0b111101111,)
    assert payload[267:] == b"\x03arm\x04can0"
    assert len(payload) == schema.HEAD_SIZE + 27 * 8 + 9 + 2 + 4 + 5


def _decodes_or_refuses(data: bytes) -> None:
    try:
        sample = decode_forces(data)
    except SchemaError:
        return
    assert np.isfinite(sample.frame.force_N).all()
    assert np.array_equal(sample.frame.valid, sample.frame.reason == 0)


@given(st.binary(max_size=400))
def test_any_bytes_are_a_sample_or_a_schema_error(data: bytes) -> None:
    _decodes_or_refuses(data)


@given(st.data())
def test_a_damaged_sample_is_refused_or_still_consistent(data: st.DataObject) -> None:
    payload = bytearray(encode_forces(_typical(), b"arm", b"can0", 0.0, 0.0))
    cut = data.draw(st.integers(0, len(payload)))
    flips = data.draw(st.lists(st.tuples(st.integers(0, len(payload) - 1),
                                         st.integers(0, 255)), max_size=4))
    for at, value in flips:
        payload[at] = value
    _decodes_or_refuses(bytes(payload[:cut]))


@pytest.mark.parametrize(("change", "problem"), [
    (lambda p: bytes([2]) + p[1:], "schema version 2"),
    (lambda p: p[:20], "shorter than the 40-byte head"),
    (lambda p: p[:260], "need at least"),
    (lambda p: p[:265] + b"\x00\x00" + p[267:], "valid bits 0x0000 and reasons disagree"),
    (lambda p: p[:40] + struct.pack("<d", float("nan")) + p[48:], "not finite"),
    (lambda p: p[:267] + b"\x09arm", "host name at byte 267: 9 bytes"),
    (lambda p: p + b"\x05\x10\x00abc", "extension 5 at byte"),
])
def test_what_is_wrong_is_said(change: object, problem: str) -> None:
    payload = encode_forces(_typical(), b"arm", b"can0", 0.0, 0.0)
    with pytest.raises(SchemaError, match=problem):
        decode_forces(change(payload))  # type: ignore[operator]


@given(st.binary(max_size=200))
def test_events_are_msgpack_maps_of_a_known_version_or_refused(data: bytes) -> None:
    try:
        event = schema.decode_event(data)
    except SchemaError:
        return
    assert isinstance(event, dict) and event["v"] == schema.EVENT_VERSION


def test_an_event_round_trips_and_another_version_is_refused() -> None:
    fields = {"host": "arm", "patch": 3, "data": b"\x04\x01", "state": "lost"}
    assert schema.decode_event(schema.encode_event(fields)) == {"v": 1, **fields}
    with pytest.raises(SchemaError, match="event version 2"):
        schema.decode_event(msgpack.packb({"v": 2}))
    with pytest.raises(SchemaError, match="an event is a map"):
        schema.decode_event(msgpack.packb([1, 2]))


@pytest.mark.parametrize("name", ["", "a/b", "a*", "x$", "q?", "h#", "a b", "@admin"])
def test_names_that_cannot_be_a_key_chunk_are_refused(name: str) -> None:
    assert schema.key_chunk_problem(name) is not None
    with pytest.raises(SchemaError, match="host"):
        schema.forces_selector(host=name or "a/b")


def test_selectors_name_one_patch_bus_host_or_the_skin() -> None:
    assert schema.forces_selector() == "canskin/*/*/forces/*"
    assert schema.forces_selector("robot/skin", host="arm", patch=3) == \
        "robot/skin/arm/*/forces/3"
    assert schema.forces_selector(bus="can0") == "canskin/*/can0/forces/*"
    with pytest.raises(SchemaError, match="patch"):
        schema.forces_selector(patch=128)
