"""pcap files of SocketCAN frames (LINKTYPE_CAN_SOCKETCAN = 227), as Wireshark reads them.

A record is the kernel's ``struct can_frame`` / ``struct canfd_frame``: the CAN id with
its flags (EFF 0x80000000, RTR 0x40000000, ERR 0x20000000) as a **big-endian** u32,
the payload length, the CAN FD flags (BRS 0x01, ESI 0x02, FDF 0x04), two reserved bytes
and the data padded to 8 (CAN_MTU = 16 bytes) or 64 (CANFD_MTU = 72 bytes). Writing the
full MTU is what a SocketCAN capture produces; Wireshark 4.0 tells CAN FD from classic
CAN by that record length. The writer uses microsecond timestamps (the classic pcap
magic); the reader takes both byte orders and nanosecond files. pcapng files have a
reader of their own (``canbus.tools.pcapng``), which ``Recording`` picks by content.

:class:`PcapWriter` and :class:`PcapReader` are python-can message writer and reader
classes, so they plug into anything that takes a ``can.Listener`` or iterates messages.
A damaged file raises :class:`RecordingError` naming the frame (1-based, as Wireshark
numbers them) that is truncated or corrupt; no message past it is yielded.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator
from typing import Any, BinaryIO

import can
from can.io.generic import BinaryIOMessageReader, BinaryIOMessageWriter

from skin.errors import RecordingError

LINKTYPE_CAN_SOCKETCAN = 227
CAN_EFF_FLAG, CAN_RTR_FLAG, CAN_ERR_FLAG = 0x8000_0000, 0x4000_0000, 0x2000_0000
CAN_EFF_MASK, CAN_SFF_MASK = 0x1FFF_FFFF, 0x7FF
CANFD_BRS, CANFD_ESI, CANFD_FDF = 0x01, 0x02, 0x04
CAN_MTU, CANFD_MTU = 16, 72
FD_LENGTHS = frozenset((0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64))

_MAGIC_US, _MAGIC_NS, _PCAPNG = 0xA1B2C3D4, 0xA1B23C4D, 0x0A0D0D0A
_GLOBAL = struct.Struct("<IHHiIII")
_FRAME_HEAD = struct.Struct(">IBBBB")


def encode_frame(msg: can.Message) -> bytes:
    """One message as a SocketCAN ``can_frame`` (16 bytes) or ``canfd_frame`` (72 bytes)."""
    can_id = msg.arbitration_id & (CAN_EFF_MASK if msg.is_extended_id else CAN_SFF_MASK)
    if msg.is_extended_id:
        can_id |= CAN_EFF_FLAG
    if msg.is_remote_frame:
        can_id |= CAN_RTR_FLAG
    if msg.is_error_frame:
        can_id = CAN_ERR_FLAG | (msg.arbitration_id & CAN_EFF_MASK)
    data = bytes(msg.data or b"")
    if msg.is_fd:
        flags = CANFD_FDF | (CANFD_BRS if msg.bitrate_switch else 0)
        flags |= CANFD_ESI if msg.error_state_indicator else 0
        return _FRAME_HEAD.pack(can_id, len(data), flags, 0, 0) + data.ljust(64, b"\0")
    length = msg.dlc if msg.is_remote_frame else len(data)
    return _FRAME_HEAD.pack(can_id, length, 0, 0, 0) + data.ljust(8, b"\0")


def decode_frame(record: bytes, timestamp: float, *, source: str = "<bytes>",
                 frame: int | None = None) -> can.Message:
    """A SocketCAN record back into a message; :class:`RecordingError` if it is not one."""
    if len(record) < _FRAME_HEAD.size:
        raise RecordingError(source, frame, f"{len(record)}-byte record is shorter than the "
                             "8-byte SocketCAN header")
    can_id, length, flags, _, _ = _FRAME_HEAD.unpack_from(record)
    fd = len(record) == CANFD_MTU or bool(flags & CANFD_FDF)
    room = len(record) - _FRAME_HEAD.size
    if fd and length not in FD_LENGTHS:
        raise RecordingError(source, frame, f"CAN FD length {length} is not a valid FD length")
    extended, remote, error = (bool(can_id & f) for f in (CAN_EFF_FLAG, CAN_RTR_FLAG,
                                                             CAN_ERR_FLAG))
    if not fd and length > 8 and not remote:
        raise RecordingError(source, frame, f"classic CAN length {length} is above 8")
    data_length = 0 if remote else length
    if data_length > room:
        raise RecordingError(source, frame, f"length {length} but only {room} data bytes")
    if not extended and not error and can_id & CAN_EFF_MASK & ~CAN_SFF_MASK:
        raise RecordingError(source, frame, f"11-bit id 0x{can_id & CAN_EFF_MASK:X} "
                             "has bits above 0x7FF")
    return can.Message(
        timestamp=timestamp, arbitration_id=can_id & CAN_EFF_MASK, is_extended_id=extended,
        is_remote_frame=remote and not error, is_error_frame=error, is_fd=fd,
        bitrate_switch=bool(flags & CANFD_BRS), error_state_indicator=bool(flags & CANFD_ESI),
        dlc=length, data=record[_FRAME_HEAD.size:_FRAME_HEAD.size + data_length],
        check=False)


class PcapWriter(BinaryIOMessageWriter):
    """Writes every message it receives as one pcap record (LINKTYPE_CAN_SOCKETCAN)."""

    def __init__(self, file: str | os.PathLike[str] | BinaryIO, **kwargs: Any) -> None:
        super().__init__(file, mode="wb")
        self.file.write(_GLOBAL.pack(_MAGIC_US, 2, 4, 0, 0, CANFD_MTU, LINKTYPE_CAN_SOCKETCAN))
        self.frames = 0

    def on_message_received(self, msg: can.Message) -> None:
        record = encode_frame(msg)
        # the correctly rounded decimal, as candump -L and python-can's .log write it
        seconds, micros = divmod(int(f"{msg.timestamp:.6f}".replace(".", "")), 1_000_000)
        self.file.write(struct.pack("<IIII", seconds, micros, len(record), len(record)))
        self.file.write(record)
        self.frames += 1


class PcapReader(BinaryIOMessageReader):
    """Iterates the messages of a pcap file of SocketCAN frames, checking every record."""

    def __init__(self, file: str | os.PathLike[str] | BinaryIO, **kwargs: Any) -> None:
        super().__init__(file, mode="rb")
        self.source = os.fspath(file) if isinstance(file, str | os.PathLike) else \
            str(getattr(file, "name", "<stream>"))
        head = self.file.read(_GLOBAL.size)
        if len(head) < 4:
            raise RecordingError(self.source, None, "not a pcap file: empty or cut short")
        magic = struct.unpack("<I", head[:4])[0]
        if magic == _PCAPNG:
            raise RecordingError(self.source, None, "a pcapng file: read it with "
                                 "canbus.tools.pcapng.PcapngReader, or convert it with "
                                 "`editcap -F pcap IN OUT`")
        order = next((o for o in "<>" if struct.unpack(f"{o}I", head[:4])[0]
                      in (_MAGIC_US, _MAGIC_NS)), None)
        if order is None:
            raise RecordingError(self.source, None, f"not a pcap file (magic 0x{magic:08X})")
        if len(head) < _GLOBAL.size:
            raise RecordingError(self.source, None, "pcap header cut short "
                                 f"({len(head)} of {_GLOBAL.size} bytes)")
        fields = struct.unpack(f"{order}IHHiIII", head)
        self._scale = 1e-9 if fields[0] == _MAGIC_NS else 1e-6
        link = fields[6] & 0x0FFF_FFFF
        if link != LINKTYPE_CAN_SOCKETCAN:
            raise RecordingError(self.source, None, f"link type {link} is not "
                                 f"LINKTYPE_CAN_SOCKETCAN ({LINKTYPE_CAN_SOCKETCAN})")
        self._record = struct.Struct(f"{order}IIII")

    def __iter__(self) -> Iterator[can.Message]:
        read, record_head = self.file.read, self._record
        frame = 0
        while True:
            head = read(record_head.size)
            if not head:
                break
            frame += 1
            if len(head) < record_head.size:
                raise RecordingError(self.source, frame, "truncated record header "
                                     f"({len(head)} of {record_head.size} bytes)")
            seconds, fraction, included, original = record_head.unpack(head)
            if not _FRAME_HEAD.size <= included <= CANFD_MTU or original < included:
                raise RecordingError(self.source, frame, f"record of {included} bytes "
                                     f"(original {original}) is not a SocketCAN frame")
            record = read(included)
            if len(record) < included:
                raise RecordingError(self.source, frame, f"truncated ({len(record)} of "
                                     f"{included} bytes)")
            yield decode_frame(record, seconds + fraction * self._scale, source=self.source,
                               frame=frame)
        self.stop()
