"""The files of a recording, each complete after every write: python-can's writers (and
ours for .log and .pcap) writing to memory, and the segment that puts each batch into its
file in one write with the footer after it (.log, .asc, .pcap), or brings a .blf's
containers and header up to date (:mod:`canbus.tools.recorder` uses them)."""

from __future__ import annotations

import abc
import functools
import io
import os
import re
import time
from pathlib import Path
from typing import Any, cast

import can
from can.io.generic import MessageWriter

from canbus.tools.pcap import PcapWriter
from skin.errors import ConfigError, SkinError
from skin.inputs.outputs import (
    create_beside,
    create_in_place,
    discard,
    put_in_place,
    reserve,
    write_error,
)

DEFAULT_LOG_CHANNEL = "can0"
_INTERFACE_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_-]{0,14}")  # a Linux interface name


def log_channel_name(bus_channel: object) -> str:
    """The interface name a .log recording of ``bus_channel`` gives every frame.

    A .log line names its interface (``(t) can0 181#...``) and can-utils' log2asc takes
    the names to convert on its command line, so the name must be one an interface can
    have: the bus's own channel when it is one (``skin0``, ``vcan0``), else ``can0``
    (udp_multicast's channel is a multicast group address).
    """
    if isinstance(bus_channel, str) and _INTERFACE_NAME.fullmatch(bus_channel):
        return bus_channel
    return DEFAULT_LOG_CHANNEL


def check_channel_name(name: str, field: str = "--channel-name") -> str:
    if not _INTERFACE_NAME.fullmatch(name):
        raise ConfigError(field, f"{name!r} is not an interface name (a letter, then up to "
                          "14 letters, digits, '_' or '-', e.g. can0)")
    return name


class CandumpLogWriter(can.CanutilsLogWriter):
    """python-can's .log writer that names every frame's interface ``channel`` and keeps
    a remote frame's DLC as candump does (``123#R4``).

    python-can writes a frame's own ``msg.channel`` when it has one (virtual: the channel
    name; udp_multicast: none, so ``vcan0``), which log2asc cannot be told in advance.
    python-can 4.6 writes every remote frame as ``123#R``, which reads back with DLC 0;
    candump, log2asc and python-can's reader all take ``R`` followed by the DLC.
    """

    def __init__(self, file: Any, channel: str = DEFAULT_LOG_CHANNEL, **kwargs: Any) -> None:
        super().__init__(file, channel=check_channel_name(channel, "channel"), **kwargs)

    def on_message_received(self, msg: can.Message) -> None:
        own = msg.channel
        msg.channel = self.channel  # put back below: other listeners share the message
        try:
            self._write(msg)
        finally:
            msg.channel = own

    def _write(self, msg: can.Message) -> None:
        if not msg.is_remote_frame or msg.is_fd or not 0 < msg.dlc <= 8:
            super().on_message_received(msg)
            return
        real, self.file = self.file, io.StringIO()
        try:
            super().on_message_received(msg)
            line = self.file.getvalue()
        finally:
            self.file = real
        real.write(line.replace("#R", f"#R{msg.dlc}", 1))


WRITERS: dict[str, type[MessageWriter]] = {
    ".log": CandumpLogWriter, ".asc": can.ASCWriter, ".blf": can.BLFWriter, ".pcap": PcapWriter,
}
FORMATS = (*WRITERS, ".mcap")
"""Every format a recording is written in: python-can's writers' and MCAP
(:mod:`canbus.tools.mcap_writer`, with the ``mcap`` extra)."""
_TEXT = frozenset((".log", ".asc"))


class _KeptText(io.StringIO):
    """The writer's file: closing it (the writer's stop) keeps what it holds."""

    def close(self) -> None:
        pass


class _KeptBytes(io.BytesIO):
    def close(self) -> None:
        pass


def _memory(suffix: str) -> _KeptText | _KeptBytes:
    return _KeptText(newline="\n") if suffix in _TEXT else _KeptBytes()


def _encode(data: str | bytes) -> bytes:
    return data.encode("utf-8") if isinstance(data, str) else data


@functools.cache
def _footer(suffix: str) -> bytes:
    """What python-can's writer adds when it stops (.asc: ``End TriggerBlock``)."""
    memory = _memory(suffix)
    writer = WRITERS[suffix](cast(Any, memory))
    start = len(memory.getvalue())
    writer.stop()
    return _encode(memory.getvalue()[start:])


class LiveBLFWriter(can.BLFWriter):
    """python-can's BLF writer that can bring the file up to date while it runs."""

    def checkpoint(self) -> None:
        """Write every buffered object (compressed containers), then the header with the
        object count, sizes and stop time so far: the file is then a complete .blf."""
        while self._buffer_size:
            self._flush()
        self.file.flush()  # the containers reach the file before the header counts them
        end = self.file.tell()
        self.file.seek(0)
        self._write_header(end)
        self.file.flush()
        self.file.seek(end)


class Segment(abc.ABC):
    """One file of a recording and its writer; complete on disk after each checkpoint()."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.frames = 0
        self.opened = time.monotonic()

    @abc.abstractmethod
    def writer(self) -> can.Listener:
        """The python-can writer that takes the frames."""

    @abc.abstractmethod
    def size(self) -> int:
        """The bytes of the file, as written so far plus what the next write adds."""

    @abc.abstractmethod
    def buffered(self) -> int:
        """The bytes the writer holds in memory for the next write."""

    @abc.abstractmethod
    def checkpoint(self) -> None:
        """Write what the writer holds: the file is then complete up to the last frame."""

    @abc.abstractmethod
    def close(self) -> None:
        """The writer's end (footer, header), everything written, synced and closed."""


class StreamSegment(Segment):
    """.log, .asc, .pcap: the writer writes to memory; each checkpoint appends the batch,
    and the footer after it, in one write at the end of what is already there."""

    def __init__(self, path: Path, suffix: str, **kwargs: Any) -> None:
        super().__init__(path)
        self._memory = _memory(suffix)
        self._writer = WRITERS[suffix](cast(Any, self._memory), **kwargs)
        self._footer = _footer(suffix)
        self._end = 0  # bytes on disk before the footer

        def header(fd: int) -> None:
            self._fd = fd
            head = self._take()
            self._write(head + self._footer)  # a valid, empty recording from the start
            self._end = len(head)

        self._fd = create_in_place(path, header)

    def writer(self) -> can.Listener:
        return self._writer

    def size(self) -> int:
        return self._end + self._memory.tell() + len(self._footer)

    def buffered(self) -> int:
        return self._memory.tell()

    def _take(self) -> bytes:
        data = self._memory.getvalue()
        self._memory.seek(0)
        self._memory.truncate()
        return _encode(data)

    def _write(self, data: bytes) -> None:
        """``data`` at the end of the content, over the footer."""
        view, offset = memoryview(data), self._end
        while view:
            done = os.pwrite(self._fd, view, offset)
            view, offset = view[done:], offset + done

    def checkpoint(self) -> None:
        data = self._take()
        if data:
            self._write(data + self._footer)
            self._end += len(data)

    def close(self) -> None:
        try:
            self._writer.stop()  # its footer goes to memory, after the last frames
            data = self._take()
            self._write(data)
            self._end += len(data)
            os.ftruncate(self._fd, self._end)
            os.fsync(self._fd)
        finally:
            os.close(self._fd)


class BlfSegment(Segment):
    def __init__(self, path: Path) -> None:
        super().__init__(path)
        fd, tmp = create_beside(path)  # renamed over the target once it is a .blf
        file = os.fdopen(fd, "w+b")
        try:
            self._writer = LiveBLFWriter(file)
            self._writer.checkpoint()
            reserve(fd)
        except BaseException as err:
            file.close()
            discard(tmp)
            if isinstance(err, OSError) and not isinstance(err, SkinError):
                raise write_error(path, err) from err
            raise
        try:
            put_in_place(tmp, path)
        except BaseException:
            file.close()
            raise

    def writer(self) -> can.Listener:
        return self._writer

    def size(self) -> int:
        return int(self._writer.file.tell())

    def buffered(self) -> int:
        return self._writer._buffer_size  # uncompressed objects not yet in a container

    def checkpoint(self) -> None:
        self._writer.checkpoint()

    def close(self) -> None:
        try:
            self._writer.checkpoint()
            os.fsync(self._writer.file.fileno())
        finally:
            self._writer.stop()


def open_segment(path: Path, suffix: str, channel: str | None) -> Segment:
    """A file of python-can's formats (an .mcap's: ``canbus.tools.mcap_writer``)."""
    if suffix == ".blf":
        return BlfSegment(path)
    kwargs = {} if channel is None or suffix != ".log" else {"channel": channel}
    return StreamSegment(path, suffix, **kwargs)
