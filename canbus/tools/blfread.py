"""python-can's BLF reader with bounds: no endless loop, no decompression bomb.

python-can's ``BLFReader`` trusts the sizes a file declares: an object of size 0 inside a
container is parsed again and again for ever (its position never moves), an object that
claims to be shorter than its own header reads its neighbours, a header size below the
header's own length reads the rest of the file at once, and a container inflates to
whatever its deflate stream holds (a 1 MB file can take gigabytes). :class:`BoundedBLFReader`
reads the same files and yields the same messages, but:

- every object is at least as long as its headers and the record it holds, and at most
  :data:`MAX_OBJECT_BYTES`; objects are walked before python-can parses a container;
- a container declares and inflates to at most :data:`MAX_CONTAINER_BYTES` (the memory
  budget of one container; python-can's writer makes 128 KiB ones), and never to more
  than it declares;
- an unknown compression method, a header of a size it cannot have, or an object
  without its ``LOBJ`` signature is a ``BLFParseError``, which
  :class:`canbus.tools.recording.Recording` reports naming the frame.
"""

from __future__ import annotations

import zlib
from collections.abc import Generator, Iterator
from typing import Any, BinaryIO, cast

import can
from can.io import blf
from can.io.blf import BLFParseError
from can.io.generic import BinaryIOMessageReader

MAX_CONTAINER_BYTES = 16 << 20
MAX_OBJECT_BYTES = 1 << 20
MAX_HEADER_BYTES = 1 << 16
_BASE = blf.OBJ_HEADER_BASE_STRUCT.size
_HEADERS = {1: blf.OBJ_HEADER_V1_STRUCT.size, 2: blf.OBJ_HEADER_V2_STRUCT.size}
_RECORDS = {blf.CAN_MESSAGE: blf.CAN_MSG_STRUCT.size, blf.CAN_MESSAGE2: blf.CAN_MSG_STRUCT.size,
            blf.CAN_ERROR_EXT: blf.CAN_ERROR_EXT_STRUCT.size,
            blf.CAN_FD_MESSAGE: blf.CAN_FD_MSG_STRUCT.size,
            blf.CAN_FD_MESSAGE_64: blf.CAN_FD_MSG_64_STRUCT.size}


class BoundedBLFReader(can.BLFReader):
    """``can.BLFReader`` with the bounds of the module's docstring."""

    def __init__(self, file: Any, **kwargs: Any) -> None:
        BinaryIOMessageReader.__init__(self, file, mode="rb")
        size = blf.FILE_HEADER_STRUCT.size
        data = self.file.read(size)
        if len(data) < size:
            raise BLFParseError(f"file header cut short ({len(data)} of {size} bytes)")
        header = blf.FILE_HEADER_STRUCT.unpack(data)
        if header[0] != b"LOGG":
            raise BLFParseError("not a BLF file (no LOGG signature)")
        if not size <= header[1] <= MAX_HEADER_BYTES:
            raise BLFParseError(f"file header of {header[1]} bytes (must be {size}.."
                                f"{MAX_HEADER_BYTES})")
        self.file_size = header[10]
        self.uncompressed_size = header[11]
        self.object_count = header[12]
        self.start_timestamp = blf.systemtime_to_timestamp(cast(Any, header[14:22]))
        self.stop_timestamp = blf.systemtime_to_timestamp(cast(Any, header[22:30]))
        self.file.read(header[1] - size)
        self._tail = b""
        self._pos = 0

    def __iter__(self) -> Generator[can.Message, None, None]:
        read = cast(BinaryIO, self.file).read
        while True:
            data = read(_BASE)
            if not data:
                break
            if len(data) < _BASE:
                raise BLFParseError(f"object header cut short ({len(data)} of {_BASE} bytes)")
            signature, _, _, obj_size, obj_type = blf.OBJ_HEADER_BASE_STRUCT.unpack(data)
            if signature != b"LOBJ":
                raise BLFParseError("an object without its LOBJ signature")
            limit = MAX_CONTAINER_BYTES if obj_type == blf.LOG_CONTAINER else MAX_OBJECT_BYTES
            if not _BASE + (blf.LOG_CONTAINER_STRUCT.size if obj_type == blf.LOG_CONTAINER
                            else 0) <= obj_size <= limit:
                raise BLFParseError(f"object of type {obj_type} declares {obj_size} bytes")
            obj_data = read(obj_size - _BASE)
            cut = len(obj_data) < obj_size - _BASE  # the file's end: Recording says so
            if not cut:
                read(obj_size % 4)
            if obj_type == blf.LOG_CONTAINER and len(obj_data) >= blf.LOG_CONTAINER_STRUCT.size:
                yield from self._container(obj_data)
            if cut:
                break
        self.stop()

    def _container(self, obj_data: bytes) -> Iterator[can.Message]:
        method, declared = blf.LOG_CONTAINER_STRUCT.unpack_from(obj_data)
        packed = obj_data[blf.LOG_CONTAINER_STRUCT.size:]
        if declared > MAX_CONTAINER_BYTES:
            raise BLFParseError(f"a container declares {declared} bytes, more than the "
                                f"{MAX_CONTAINER_BYTES} bytes a container may hold")
        if method == blf.NO_COMPRESSION:
            data = packed
        elif method == blf.ZLIB_DEFLATE:
            data = zlib.decompressobj().decompress(packed, declared + 1)
            if len(data) > declared:
                raise BLFParseError(f"a container inflates past the {declared} bytes it "
                                    "declares")
        else:
            raise BLFParseError(f"unknown compression method {method}")
        _check_objects(self._tail + data)
        yield from self._parse_container(data)


def _check_objects(data: bytes) -> None:
    """Walk the objects of a container's data as python-can's parser will, refusing one
    whose size cannot hold its headers and record (size 0 would never move on)."""
    pos, end = 0, len(data)
    while pos + _BASE <= end:
        found = data.find(b"LOBJ", pos, pos + 8)
        if found < 0:
            return  # python-can says so itself (BLFParseError), or waits for more data
        pos = found
        if pos + _BASE > end:
            return
        _, _, version, obj_size, obj_type = blf.OBJ_HEADER_BASE_STRUCT.unpack_from(data, pos)
        if version not in _HEADERS:
            raise BLFParseError(f"object header version {version} (BLF has 1 and 2)")
        least = _BASE + _HEADERS[version] + _RECORDS.get(obj_type, 0)
        if not least <= obj_size <= MAX_OBJECT_BYTES:
            raise BLFParseError(f"object of type {obj_type} declares {obj_size} bytes (must be "
                                f"{least}..{MAX_OBJECT_BYTES})")
        pos += obj_size
