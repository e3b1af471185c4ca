"""The pcap codec (LINKTYPE_CAN_SOCKETCAN): round trips, exact bytes, damaged files."""

from __future__ import annotations

import struct
from pathlib import Path

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canbus.tools.pcap import (
    FD_LENGTHS,
    PcapReader,
    PcapWriter,
    RecordingError,
    decode_frame,
    encode_frame,
)

FILES = Path(__file__).parents[1] / "files" / "recordings"
FIELDS = ("arbitration_id", "is_extended_id", "is_remote_frame", "is_error_frame", "is_fd",
          "bitrate_switch", "error_state_indicator", "dlc")


@st.composite
def messages(draw: st.DrawFn) -> can.Message:
    kind = draw(st.sampled_from(("classic", "remote", "fd", "error")))
    extended = draw(st.booleans())
    ident = draw(st.integers(0, 0x1FFF_FFFF if extended else 0x7FF))
    stamp = draw(st.integers(0, 2**32 * 1_000_000 - 1)) / 1e6
    if kind == "classic":
        return can.Message(timestamp=stamp, arbitration_id=ident, is_extended_id=extended,
                           data=draw(st.binary(max_size=8)))
    if kind == "remote":
        return can.Message(timestamp=stamp, arbitration_id=ident, is_extended_id=extended,
                           is_remote_frame=True, dlc=draw(st.integers(0, 8)))
    if kind == "fd":
        length = draw(st.sampled_from(sorted(FD_LENGTHS)))
        return can.Message(timestamp=stamp, arbitration_id=ident, is_extended_id=extended,
                           is_fd=True, data=draw(st.binary(min_size=length, max_size=length)),
                           bitrate_switch=draw(st.booleans()),
                           error_state_indicator=draw(st.booleans()))
    return can.Message(timestamp=stamp, is_error_frame=True,
                       arbitration_id=draw(st.integers(0, 0x1FFF_FFFF)),
                       data=draw(st.binary(max_size=8)))


def _same(a: can.Message, b: can.Message) -> None:
    for name in FIELDS:
        if name == "is_extended_id" and a.is_error_frame:
            continue  # an error frame's id is the error class, not an identifier
        assert getattr(a, name) == getattr(b, name), name
    assert bytes(a.data) == bytes(b.data)
    assert round(a.timestamp * 1e6) == round(b.timestamp * 1e6)


@given(messages())
def test_frame_round_trip(msg: can.Message) -> None:
    record = encode_frame(msg)
    assert len(record) == (72 if msg.is_fd else 16)  # CANFD_MTU / CAN_MTU
    _same(decode_frame(record, msg.timestamp), msg)


@settings(max_examples=30)
@given(st.lists(messages(), max_size=20))
def test_file_round_trip(tmp_path_factory: pytest.TempPathFactory,
                         sent: list[can.Message]) -> None:
    path = tmp_path_factory.mktemp("pcap") / "x.pcap"
    writer = PcapWriter(path)
    for msg in sent:
        writer.on_message_received(msg)
    writer.stop()
    with PcapReader(path) as reader:
        got = list(reader)
    assert len(got) == len(sent)
    for a, b in zip(got, sent, strict=True):
        _same(a, b)


def test_exact_bytes(tmp_path: Path) -> None:
    path = tmp_path / "one.pcap"
    writer = PcapWriter(path)
    writer.on_message_received(can.Message(timestamp=1.25, arbitration_id=0x181,
                                           data=b"\x20\x4e", is_extended_id=False))
    writer.on_message_received(can.Message(timestamp=2.0, arbitration_id=0x1ABCDE,
                                           is_extended_id=True, is_remote_frame=True, dlc=3))
    writer.stop()
    header = struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 72, 227)
    first = struct.pack("<IIII", 1, 250_000, 16, 16) + \
        bytes.fromhex("00000181 02 00 0000") + b"\x20\x4e" + bytes(6)
    second = struct.pack("<IIII", 2, 0, 16, 16) + \
        bytes.fromhex("C01ABCDE 03 00 0000") + bytes(8)
    assert path.read_bytes() == header + first + second


def _pcap(records: list[bytes], *, order: str = "<", nanos: bool = False,
          link: int = 227) -> bytes:
    magic = 0xA1B23C4D if nanos else 0xA1B2C3D4
    out = struct.pack(f"{order}IHHiIII", magic, 2, 4, 0, 0, 72, link)
    for k, record in enumerate(records):
        out += struct.pack(f"{order}IIII", 10, k * 1000, len(record), len(record)) + record
    return out


def test_reads_big_endian_and_nanosecond_files(tmp_path: Path) -> None:
    record = bytes.fromhex("00000701 01 00 0000 05")  # unpadded: 9 bytes
    path = tmp_path / "be.pcap"
    path.write_bytes(_pcap([record, record], order=">", nanos=True))
    with PcapReader(path) as reader:
        got = list(reader)
    assert [(m.arbitration_id, bytes(m.data)) for m in got] == [(0x701, b"\x05")] * 2
    assert got[1].timestamp == pytest.approx(10 + 1e-6, abs=1e-9)


@pytest.mark.parametrize(("content", "message"), [
    (b"", "not a pcap file: empty"),
    (struct.pack("<I", 0x0A0D0D0A) + bytes(40), "a pcapng file: read it with"),
    (b"GIF89a" + bytes(30), "not a pcap file (magic"),
    (_pcap([])[:20], "pcap header cut short (20 of 24 bytes)"),
    (_pcap([], link=1), "link type 1 is not LINKTYPE_CAN_SOCKETCAN (227)"),
])
def test_file_level_errors(tmp_path: Path, content: bytes, message: str) -> None:
    path = tmp_path / "bad.pcap"
    path.write_bytes(content)
    with pytest.raises(RecordingError, match=message.replace("(", r"\(").replace(")", r"\)")):
        PcapReader(path)


@pytest.mark.parametrize(("record", "message"), [
    (bytes.fromhex("00000181 09 00 0000") + bytes(8), "classic CAN length 9 is above 8"),
    (bytes.fromhex("00000881 01 00 0000") + bytes(8), "has bits above 0x7FF"),
    (bytes.fromhex("00000181 09 04 0000") + bytes(64), "CAN FD length 9 is not a valid"),
    (bytes.fromhex("00000181 08 00 0000") + bytes(4), "length 8 but only 4 data bytes"),
    (bytes.fromhex("0000"), r"record of 2 bytes \(original 2\) is not a SocketCAN frame"),
])
def test_record_errors_name_the_frame(tmp_path: Path, record: bytes, message: str) -> None:
    good = bytes.fromhex("00000080 00 00 0000") + bytes(8)
    path = tmp_path / "bad.pcap"
    path.write_bytes(_pcap([good, good, record, good]))
    got: list[can.Message] = []
    with pytest.raises(RecordingError, match=f"frame 3: .*{message}") as info, \
            PcapReader(path) as reader:
        got.extend(reader)
    assert info.value.frame == 3
    assert len(got) == 2  # nothing from the bad frame on


@pytest.mark.parametrize(("name", "frame", "message"), [
    ("truncated.pcap", 4, "truncated (10 of 16 bytes)"),
    ("corrupt.pcap", 3, "record of 300 bytes (original 16) is not a SocketCAN frame"),
])
def test_damaged_files(name: str, frame: int, message: str) -> None:
    got: list[can.Message] = []
    with pytest.raises(RecordingError) as info, PcapReader(FILES / name) as reader:
        got.extend(reader)
    assert str(info.value) == f"{FILES / name}: frame {frame}: {message}"
    assert len(got) == frame - 1


def test_python_can_logger_and_reader_take_pcap_by_entry_point(tmp_path: Path) -> None:
    """pyproject registers the codec in python-can's plug-in groups: its own Logger and
    LogReader (and so can.logger / can.player) write and read .pcap."""
    path = tmp_path / "plug-in.pcap"
    sent = [can.Message(timestamp=1.5 + k, arbitration_id=0x181 + k, is_extended_id=False,
                        data=bytes([k] * 8)) for k in range(3)]
    with can.Logger(path) as logger:
        assert isinstance(logger, PcapWriter)
        for msg in sent:
            logger.on_message_received(msg)
    got = list(can.LogReader(path))
    assert [(m.arbitration_id, bytes(m.data), m.timestamp) for m in got] == \
        [(m.arbitration_id, bytes(m.data), m.timestamp) for m in sent]
