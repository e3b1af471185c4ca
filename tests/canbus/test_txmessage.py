"""TxMessage: the frames we send are ordinary ``can.Message`` s to every receiver."""

from __future__ import annotations

import copy

import can
import pytest
from hypothesis import given
from hypothesis import strategies as st

from canbus import txmessage
from canbus.txmessage import TxMessage


@pytest.fixture(params=[True, False], ids=["direct", "init"])
def direct(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> bool:
    """Both ways of building: fields set directly, and the fallback through __init__."""
    if request.param and txmessage._message_fields() != txmessage.FIELDS:
        pytest.skip("this python-can's Message has other fields: only __init__ builds it")
    monkeypatch.setattr(txmessage, "DIRECT", request.param)
    return bool(request.param)


def test_every_field_of_the_installed_can_message_is_set(direct: bool) -> None:
    """Built field by field or by __init__, no slot of python-can's Message is left unset."""
    names = {n for cls in can.Message.__mro__ for n in getattr(cls, "__slots__", ())}
    frame = TxMessage.data_frame(0x181, b"\x01")
    for msg in (frame, copy.deepcopy(frame)):
        for name in names - {"__weakref__"}:
            getattr(msg, name)  # AttributeError if a field was never set


@given(cob_id=st.integers(0, 0x7FF), data=st.binary(max_size=8))
def test_data_frame_equals_the_message_python_can_builds(cob_id: int, data: bytes) -> None:
    installed = txmessage.DIRECT
    for mode in {installed, False}:
        txmessage.DIRECT = mode
        try:
            frame = TxMessage.data_frame(cob_id, data)
        finally:
            txmessage.DIRECT = installed
        expected = can.Message(arbitration_id=cob_id, data=data, is_extended_id=False)
        assert frame.equals(expected, timestamp_delta=0.0)
        assert repr(frame) == repr(expected)
        assert type(frame.data) is bytearray and frame.dlc == len(data) and frame.is_rx
        copied = copy.deepcopy(frame)
        assert type(copied) is can.Message and copied.equals(expected, timestamp_delta=0.0)


def test_deep_copy_is_an_equal_independent_message(direct: bool) -> None:
    msg = TxMessage(timestamp=1.5, arbitration_id=0x1AB, is_extended_id=False,
                    data=b"\x01\x02\x03", channel=[1, 2], is_rx=False)
    clone = copy.deepcopy(msg)
    assert type(clone) is can.Message
    assert clone.equals(msg, timestamp_delta=0.0)
    assert clone.channel == [1, 2] and clone.channel is not msg.channel
    clone.data[0] = 0xFF
    clone.channel.append(3)
    assert msg.data == bytearray(b"\x01\x02\x03") and msg.channel == [1, 2]
    for flags in ({"is_remote_frame": True, "dlc": 4}, {"is_error_frame": True},
                  {"is_fd": True, "bitrate_switch": True, "error_state_indicator": True,
                   "data": bytes(range(12))}):
        original = TxMessage(arbitration_id=0x123, channel="can0", **flags)
        assert copy.deepcopy(original).equals(original, timestamp_delta=0.0)


def test_data_frame_does_not_share_the_payload(direct: bool) -> None:
    payload = bytearray(b"\x01\x02")
    frame = TxMessage.data_frame(0x181, payload)
    payload[0] = 0xFF
    assert frame.data == bytearray(b"\x01\x02")


def test_a_frame_crosses_a_virtual_bus_as_a_plain_message(
        request: pytest.FixtureRequest, direct: bool) -> None:
    with can.Bus(interface="virtual", channel=request.node.name) as tx, \
            can.Bus(interface="virtual", channel=request.node.name) as rx:
        tx.send(TxMessage.data_frame(0x181, b"\x10\x20"))
        got = rx.recv(1.0)
    assert got is not None and type(got) is can.Message
    assert (got.arbitration_id, bytes(got.data), got.is_extended_id) == (0x181, b"\x10\x20", False)
    assert got.timestamp > 0 and got.channel == request.node.name
