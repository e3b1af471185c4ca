"""pcapng files of SocketCAN frames, as dumpcap and Wireshark write them by default.

A pcapng file is a sequence of blocks: a section header (its byte-order magic says the
byte order), interface descriptions (link type, timestamp resolution ``if_tsresol``), and
packets (enhanced packet blocks, with their interface and a 64-bit timestamp; simple
packet blocks, without one). Every interface that carries packets must be
LINKTYPE_CAN_SOCKETCAN (227); each packet is then a ``can_frame`` / ``canfd_frame``
(:func:`canbus.tools.pcap.decode_frame`). Other blocks (name resolution, interface
statistics, custom ones) are skipped. A damaged file raises :class:`RecordingError`
naming the packet (1-based, as Wireshark numbers them); nothing past it is yielded.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, BinaryIO

import can
from can.io.generic import BinaryIOMessageReader

from canbus.tools.pcap import LINKTYPE_CAN_SOCKETCAN, decode_frame
from skin.errors import RecordingError

SECTION_HEADER, INTERFACE, SIMPLE_PACKET, ENHANCED_PACKET = 0x0A0D0D0A, 1, 3, 6
_BYTE_ORDER = 0x1A2B3C4D
_OPT_END, _OPT_TSRESOL = 0, 9


@dataclass(frozen=True)
class _Interface:
    link: int
    seconds_per_tick: float


MAX_BLOCK_BYTES = 1 << 20
"""A block is read whole: bounded, so a corrupt length cannot ask for gigabytes."""


class PcapngReader(BinaryIOMessageReader):
    """Iterates the CAN messages of a pcapng file, checking every block."""

    def __init__(self, file: str | os.PathLike[str] | BinaryIO, **kwargs: Any) -> None:
        super().__init__(file, mode="rb")
        self.source = os.fspath(file) if isinstance(file, str | os.PathLike) else \
            str(getattr(file, "name", "<stream>"))
        head = self.file.read(12)
        if len(head) < 12 or struct.unpack("<I", head[:4])[0] != SECTION_HEADER:
            raise RecordingError(self.source, None, "not a pcapng file (no section header)")
        self.file.seek(0)

    def __iter__(self) -> Iterator[can.Message]:
        order = "<"
        interfaces: list[_Interface] = []
        packet = 0
        while True:
            head = self.file.read(8)
            if not head:
                break
            if len(head) < 8:
                raise self._fail(packet + 1, "block header cut short (truncated file)")
            kind = struct.unpack("<I", head[:4])[0]
            if kind == SECTION_HEADER:
                order = self._section_order(head)
                interfaces = []
            kind, length = struct.unpack(f"{order}II", head)
            if length < 12 or length % 4:
                raise self._fail(packet + 1, f"block of {length} bytes is not a pcapng block")
            if length > MAX_BLOCK_BYTES:
                raise self._fail(packet + 1, f"block of {length} bytes, more than the "
                                 f"{MAX_BLOCK_BYTES} a CAN capture's block may have")
            body = self.file.read(length - 8)
            if len(body) < length - 8:
                raise self._fail(packet + 1, f"block cut short ({len(body) + 8} of {length} "
                                 "bytes: truncated file)")
            if struct.unpack(f"{order}I", body[-4:])[0] != length:
                raise self._fail(packet + 1, "block lengths disagree (corrupt block)")
            body = body[:-4]
            if kind == INTERFACE:
                interfaces.append(self._interface(body, order, packet + 1))
            elif kind in (ENHANCED_PACKET, SIMPLE_PACKET):
                packet += 1
                yield self._packet(kind, body, order, interfaces, packet)
        self.stop()

    def _section_order(self, head: bytes) -> str:
        magic = self.file.read(4)
        self.file.seek(-4, os.SEEK_CUR)
        for order in "<>":
            if len(magic) == 4 and struct.unpack(f"{order}I", magic)[0] == _BYTE_ORDER:
                return order
        raise RecordingError(self.source, None, "pcapng section header without its "
                             "byte-order magic")

    def _interface(self, body: bytes, order: str, packet: int) -> _Interface:
        if len(body) < 8:
            raise self._fail(packet, "interface description cut short")
        link = struct.unpack(f"{order}H", body[:2])[0]
        tick = 1e-6
        at = 8
        while at + 4 <= len(body):
            code, size = struct.unpack(f"{order}HH", body[at:at + 4])
            if code == _OPT_END:
                break
            if code == _OPT_TSRESOL and size >= 1:
                value = body[at + 4]
                tick = 2.0 ** -(value & 0x7F) if value & 0x80 else 10.0 ** -value
            at += 4 + size + (-size % 4)
        return _Interface(link, tick)

    def _packet(self, kind: int, body: bytes, order: str, interfaces: list[_Interface],
                packet: int) -> can.Message:
        if kind == SIMPLE_PACKET:
            interface_id, timestamp = 0, 0.0
            captured = len(body) - 4
            data = body[4:]
        else:
            if len(body) < 20:
                raise self._fail(packet, "packet block cut short")
            interface_id, high, low, captured, _ = struct.unpack(f"{order}IIIII", body[:20])
            data = body[20:]
            if interface_id < len(interfaces):
                timestamp = ((high << 32) | low) * interfaces[interface_id].seconds_per_tick
        if interface_id >= len(interfaces):
            raise self._fail(packet, f"packet on interface {interface_id}, which the file "
                             "does not describe")
        link = interfaces[interface_id].link
        if link != LINKTYPE_CAN_SOCKETCAN:
            raise self._fail(packet, f"link type {link} is not LINKTYPE_CAN_SOCKETCAN "
                             f"({LINKTYPE_CAN_SOCKETCAN})")
        if captured > len(data):
            raise self._fail(packet, f"captured length {captured} beyond its block")
        return decode_frame(data[:captured], timestamp, source=self.source, frame=packet)

    def _fail(self, packet: int, problem: str) -> RecordingError:
        return RecordingError(self.source, packet, problem)
