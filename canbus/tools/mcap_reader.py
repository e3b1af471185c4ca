"""Read a canskin MCAP recording back: its CAN frames as python-can messages
(:class:`McapFrames`, the reader :class:`~canbus.tools.recording.Recording` uses for
.mcap) and its taxel clouds (:func:`taxel_points`; ``canbus.offline.mcap.read_forces``
makes the host's ``ForceFrame`` of each).

The file is read as a stream, record by record in file order (the order the frames
crossed the bus), with the ``mcap`` library's stream reader and its chunk CRC checks, so
a file whose writer was killed reads up to its cut. Problems are ``ValueError`` (not
MCAP, a CAN topic with another schema, a message that does not decode) or ``EOFError``
(the file ends before its footer); :class:`~canbus.tools.recording.Recording` names the
frame.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import IO, Any, cast

import can
import numpy as np

from canbus.tools import mcap_messages as m

MAGIC = b"\x89MCAP0\r\n"
CHUNK_LIMIT = 1 << 28
"""The largest chunk inflated (ours are a few MiB): a damaged size is an error, not an
allocation."""
_CAN_SCHEMAS = {m.FRAMES_TOPIC: m.FRAME, m.FD_FRAMES_TOPIC: m.FD_FRAME}


def check_magic(file: IO[bytes]) -> None:
    head = file.read(len(MAGIC))
    file.seek(0)
    if head != MAGIC:
        raise ValueError(f"not an MCAP file (it starts {head[:8]!r})")


def messages(file: IO[bytes]) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, schema name, log time ns, data) of every message, in file order; EOFError
    when the file ends before its footer."""
    import zstandard
    from mcap.exceptions import EndOfFile, McapError
    from mcap.records import Channel, Chunk, Footer, Message, Schema
    from mcap.stream_reader import StreamReader, breakup_chunk

    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, str]] = {}
    reader = StreamReader(cast(IO[bytes], _Bounded(file)), emit_chunks=True, validate_crcs=True,
                          record_size_limit=None)
    try:
        for outer in reader.records:
            inner = _inflated(outer, breakup_chunk) if isinstance(outer, Chunk) else [outer]
            for record in inner:
                if isinstance(record, Footer):
                    return
                item = _item(record, schemas, channels, Message, Schema, Channel)
                if item is not None:
                    yield item
    except EndOfFile as err:
        raise EOFError("the file ends before its footer (truncated: its writer did not "
                       "finish it)") from err
    except (McapError, zstandard.ZstdError, RuntimeError, MemoryError) as err:
        raise ValueError(f"{type(err).__name__}: {err}") from err


class _Bounded:
    """The file for the stream reader: a read never asks for more than the file holds
    (a damaged length is a short read, the reader's EndOfFile, not an allocation)."""

    def __init__(self, file: IO[bytes]) -> None:
        self._file = file

    def read(self, size: int = -1) -> bytes:
        left = os.fstat(self._file.fileno()).st_size - self._file.tell()
        return self._file.read(max(0, left if size < 0 else min(size, left)))

    def tell(self) -> int:
        return self._file.tell()


def _inflated(chunk: Any, breakup: Any) -> list[Any]:
    if chunk.uncompressed_size > CHUNK_LIMIT:
        raise ValueError(f"a chunk of {chunk.uncompressed_size} bytes inflated (at most "
                         f"{CHUNK_LIMIT})")
    return list(breakup(chunk, validate_crc=True))


def _item(record: Any, schemas: dict[int, str], channels: dict[int, tuple[str, str]],
             message: type[Any], schema: type[Any], channel: type[Any]
          ) -> tuple[str, str, int, bytes] | None:
    if isinstance(record, message):
        topic_schema = channels.get(record.channel_id)
        if topic_schema is None:
            raise ValueError(f"a message on channel {record.channel_id}, which no Channel "
                             "record declares")
        return (*topic_schema, record.log_time, record.data)
    if isinstance(record, schema):
        schemas[record.id] = record.name
    elif isinstance(record, channel):
        channels[record.id] = (record.topic, _schema_of(record, schemas))
    return None


def _schema_of(channel: Any, schemas: dict[int, str]) -> str:
    schema = schemas.get(channel.schema_id, "") if channel.schema_id else ""
    wanted = _CAN_SCHEMAS.get(channel.topic)
    if wanted is not None and (schema != wanted or channel.message_encoding != "cdr"):
        raise ValueError(f"topic {channel.topic} carries {schema or 'no schema'} "
                         f"({channel.message_encoding}), not {wanted} (cdr)")
    return schema


class McapFrames(can.io.generic.MessageReader):
    """A python-can message reader of an MCAP file's /can/frames and /can/fd_frames."""

    def __init__(self, file: IO[bytes], **kwargs: Any) -> None:
        check_magic(file)
        self.file = file

    def __iter__(self) -> Iterator[can.Message]:
        for topic, _schema, _ns, data in messages(self.file):
            if topic in _CAN_SCHEMAS:
                yield _message(m.decode_frame(data, fd=topic == m.FD_FRAMES_TOPIC))

    def stop(self) -> None:
        self.file.close()


def _message(frame: m.DecodedFrame) -> can.Message:
    return can.Message(timestamp=m.seconds_of(frame.ns), arbitration_id=frame.can_id,
                       is_extended_id=frame.extended, is_remote_frame=frame.rtr,
                       is_error_frame=frame.error, is_fd=frame.fd, dlc=frame.dlc,
                       data=frame.data, channel=frame.channel, check=False)


def taxel_points(path: str) -> Iterator[np.ndarray[Any, Any]]:
    """The points (:data:`~canbus.tools.mcap_messages.TAXEL_DTYPE`) of every taxel cloud
    of a canskin MCAP recording, in file order."""
    with open(path, "rb") as file:
        check_magic(file)
        for topic, schema, _ns, data in messages(file):
            if schema == m.TAXELS and topic.endswith("/taxels"):
                yield m.decode_taxels(data)[2]
