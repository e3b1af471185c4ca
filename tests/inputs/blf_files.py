"""Hand-made .blf files: one container around any bytes, declaring any size."""

from __future__ import annotations

import io
import zlib
from pathlib import Path

import can
from can.io import blf

RECORDINGS = Path(__file__).resolve().parents[1] / "files" / "recordings"


def blf_file(inner: bytes, declared: int | None = None, method: int = blf.ZLIB_DEFLATE) -> bytes:
    """A .blf file of one container holding ``inner`` (declaring ``declared`` bytes)."""
    good = (RECORDINGS / "good.blf").read_bytes()
    packed = zlib.compress(inner) if method == blf.ZLIB_DEFLATE else inner
    body = blf.LOG_CONTAINER_STRUCT.pack(method, len(inner) if declared is None else
                                         declared) + packed
    size = blf.OBJ_HEADER_BASE_STRUCT.size + len(body)
    obj = blf.OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", 16, 1, size, blf.LOG_CONTAINER) + body
    out = bytearray(good[:144] + obj + bytes(size % 4))
    header = list(blf.FILE_HEADER_STRUCT.unpack_from(out, 0))
    header[10] = len(out)
    out[:blf.FILE_HEADER_STRUCT.size] = blf.FILE_HEADER_STRUCT.pack(*header)
    return bytes(out)


def can_objects(count: int) -> bytes:
    """``count`` CAN frames as python-can's BLF writer lays them out in a container."""
    buffer = io.BytesIO()
    writer = can.BLFWriter(buffer, compression_level=0)  # type: ignore[arg-type]
    for k in range(count):
        writer.on_message_received(can.Message(timestamp=1.0 + k, arbitration_id=0x181,
                                               data=bytes(8)))
    writer._flush()
    data = buffer.getvalue()[144:]
    return data[blf.OBJ_HEADER_BASE_STRUCT.size + blf.LOG_CONTAINER_STRUCT.size:]
