"""Record every frame to .log (candump -L), .asc, .blf (python-can's writers) or .pcap.

A recording is a stream, written as it goes, as candump and ``can.logger`` write theirs:
the file exists under its own name from the start and is a complete, valid recording
after every write, which comes at least every :data:`FLUSH_S` (0.1 s). So whatever ends
the process (Ctrl-C, SIGTERM, kill -9, a crash), the file holds every frame received up
to the last write:

- .log and .pcap only grow, one whole batch of lines/records per write;
- .asc is written with its ``End TriggerBlock`` footer after every batch (the next batch
  overwrites it and ends with it again), so it is complete at every moment;
- .blf: the buffered objects are compressed into a container at every write and then
  the file header is rewritten with the counts and size so far (python-can's writer
  updates it only when stopped, so a killed ``can.logger`` leaves a header that says
  "empty"), so python-can and we read the whole file at every moment.

The one thing a kill -9 can still leave is a cut last line, record or container, when
the kill lands inside a write (Linux cuts a write at a page boundary for a fatal
signal): ``Recording(path, partial=True)`` and ``skin replay --partial`` read such a file
up to its last whole frame.

:class:`Recorder` is a ``can.Listener`` whose receive side only appends the message to
its own unbounded deque; a thread wakes every 10 ms and hands what has arrived to the
writer, in memory; the batch goes to the file in one write (the kernel's page cache:
it survives the process, and is synced to the disk when a file is closed). So a slow
view, a slow disk or a burst never costs a frame, and the receive thread is never held
up by the file. Rotation (``rotate_bytes``, ``rotate_s``) closes the file, complete, and
goes on in ``run.001.log``, ``run.002.log``, ... (:func:`rotated_path`).
"""

from __future__ import annotations

import abc
import contextlib
import functools
import io
import logging
import os
import re
import socket
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any, cast

import can
from can.io.generic import MessageWriter

from canbus.tools.pcap import PcapWriter
from skin.errors import ConfigError

logger = logging.getLogger(__name__)

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
_TEXT = frozenset((".log", ".asc"))


def recording_format(path: str | os.PathLike[str], *, field: str = "--record") -> str:
    """The suffix of a recording we can write; ConfigError for any other (no file touched)."""
    suffix = Path(path).suffix.lower()
    if suffix not in WRITERS:
        known = ", ".join(WRITERS)
        raise ConfigError(field, f"unknown recording format {suffix or '(no suffix)'!r} "
                          f"of {os.fspath(path)!r}; use one of {known}")
    return suffix


DEFAULT_RCVBUF = 4 * 1024 * 1024
"""The socket receive buffer the commands ask for (``--rcvbuf``): about 200 ms of
udp_multicast frames at 20,000 frames/s."""


def enlarge_receive_buffer(bus: can.BusABC, size: int) -> int | None:
    """Ask the kernel for a ``size``-byte receive buffer on a socket bus; the size granted.

    At 20,000 frames/s Linux's default (net.core.rmem_default, 208 KiB, about 12 ms of
    udp_multicast datagrams) overflows whenever the receive thread waits for the GIL a
    little longer, and the kernel drops frames. candump's ``-r`` does the same for
    SocketCAN. The grant is capped by net.core.rmem_max (Linux doubles the value asked).
    None when the bus is not a socket.
    """
    try:
        fd = bus.fileno()
    except (NotImplementedError, AttributeError, OSError, ValueError):
        return None
    if not isinstance(fd, int) or fd < 0:
        return None
    try:
        sock = socket.socket(fileno=os.dup(fd))
    except OSError:
        return None
    with contextlib.closing(sock):
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)
            return int(sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))
        except OSError:
            return None


FLUSH_S = 0.1
"""The longest a received frame waits in memory before it is written to the file."""
_FLUSH_BYTES = 1 << 20  # a burst is written out before a checkpoint is due
_POLL_S = 0.01


def rotated_path(path: str | os.PathLike[str], index: int) -> Path:
    """The ``index``-th file of a rotated recording: ``run.log``, ``run.001.log``, ..."""
    first = Path(path)
    if index == 0:
        return first
    return first.with_name(f"{first.stem}.{index:03d}{first.suffix}")


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


class _Segment(abc.ABC):
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


class _StreamSegment(_Segment):
    """.log, .asc, .pcap: the writer writes to memory; each checkpoint appends the batch,
    and the footer after it, in one write at the end of what is already there."""

    def __init__(self, path: Path, suffix: str, **kwargs: Any) -> None:
        super().__init__(path)
        self._memory = _memory(suffix)
        self._writer = WRITERS[suffix](cast(Any, self._memory), **kwargs)
        self._footer = _footer(suffix)
        self._end = 0  # bytes on disk before the footer
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o666)
        try:
            header = self._take()
            self._write(header + self._footer)  # a valid, empty recording from the start
            self._end = len(header)
        except BaseException:
            os.close(self._fd)
            raise

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


class _BlfSegment(_Segment):
    def __init__(self, path: Path) -> None:
        super().__init__(path)
        file = path.open("w+b")
        try:
            self._writer = LiveBLFWriter(file)
            self._writer.checkpoint()
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


def _open_segment(path: Path, suffix: str, channel: str | None) -> _Segment:
    if suffix == ".blf":
        return _BlfSegment(path)
    kwargs = {} if channel is None or suffix != ".log" else {"channel": channel}
    return _StreamSegment(path, suffix, **kwargs)


def _positive(value: float | None, field: str) -> float | None:
    if value is not None and not value > 0:
        raise ConfigError(field, f"must be positive, got {value}")
    return value


class Recorder(can.Listener):
    """Queues every received frame and writes it to ``path`` in a thread of its own.

    ``rotate_bytes``: go on in a new file once a file reaches this many bytes (a .blf
    counts its compressed containers, written at each checkpoint); ``rotate_s``: once a
    file has been written for this many seconds. :attr:`files` lists the files written.
    """

    def __init__(self, path: str | os.PathLike[str], *, channel: str | None = None,
                 rotate_bytes: int | None = None, rotate_s: float | None = None) -> None:
        """``channel``: the interface name every frame of a .log gets (default ``can0``);
        .asc numbers channels, .blf and .pcap name none."""
        self.suffix = recording_format(path)
        if channel is not None:
            check_channel_name(channel, "channel")
        self.rotate_bytes = _positive(rotate_bytes, "--rotate-size")
        self.rotate_s = _positive(rotate_s, "--rotate-seconds")
        self.path = Path(path)
        self.channel = channel
        self.files: list[Path] = []
        self.received = 0
        self.written = 0
        self.error: BaseException | None = None
        self.saved: Path | None = None
        self._finished = False
        self._pending: deque[can.Message] = deque()
        self._stopping = threading.Event()
        if self.rotate_bytes or self.rotate_s:
            _warn_about_earlier_files(self.path)
        self._segment = self._next_segment()
        self._thread = threading.Thread(target=self._drain, name="recorder", daemon=True)
        self._thread.start()

    @property
    def pending(self) -> int:
        """Frames received but not yet handed to the writer."""
        return len(self._pending)

    def on_message_received(self, msg: can.Message) -> None:
        self._pending.append(msg)  # atomic; no lock, no wake-up per frame
        self.received += 1

    def _next_segment(self) -> _Segment:
        path = rotated_path(self.path, len(self.files))
        segment = _open_segment(path, self.suffix, self.channel)
        self.files.append(path)
        logger.info("recording to %s", path)
        return segment

    def _rotate(self) -> None:
        self._segment.close()
        self._segment = self._next_segment()

    def _drain(self) -> None:
        """Every 10 ms, hand what has arrived to the writer; write it out every FLUSH_S."""
        flushed = time.monotonic()
        try:
            while True:
                stopping = self._stopping.wait(_POLL_S)
                if self.rotate_bytes is None:
                    self._write_all()
                else:
                    self._write_sized(self.rotate_bytes)
                now = time.monotonic()
                if self.rotate_s is not None and now - self._segment.opened >= self.rotate_s:
                    self._rotate()
                    flushed = now
                elif now - flushed >= FLUSH_S or self._segment.buffered() >= _FLUSH_BYTES:
                    self._segment.checkpoint()
                    flushed = now
                if stopping:
                    return
        except BaseException as err:  # reported by stop(); the file keeps what was written
            self.error = err

    def _write_all(self) -> None:
        pending, segment = self._pending, self._segment
        write = segment.writer().on_message_received
        count = len(pending)
        for _ in range(count):
            write(pending.popleft())
        segment.frames += count
        self.written += count

    def _write_sized(self, limit: float) -> None:
        pending = self._pending
        while pending:
            segment = self._segment
            segment.writer().on_message_received(pending.popleft())
            segment.frames += 1
            self.written += 1
            if segment.size() >= limit:
                self._rotate()

    def stop(self) -> None:
        """Write out everything queued and close the file, complete (idempotent).

        python-can's ``Notifier.stop()`` calls it; afterwards :attr:`saved` is the path.
        An error of the writer is raised here; the file keeps what was written before it.
        """
        if self._finished:
            return
        self._finished = True
        self._stopping.set()
        self._thread.join()
        if self.error is None:
            try:
                self._segment.close()
            except BaseException as err:
                self.error = err
        else:
            with contextlib.suppress(Exception):
                self._segment.close()
        if self.error is not None:
            raise OSError(f"recording to {self._segment.path} failed: {self.error}; the file "
                          "keeps the frames written before") from self.error
        self.saved = self.path


def _warn_about_earlier_files(path: Path) -> None:
    """Numbered files of an earlier rotated recording would mix with this one's."""
    pattern = re.compile(re.escape(path.stem) + r"\.\d{3,}" + re.escape(path.suffix))
    folder = path.parent if str(path.parent) else Path(".")
    with contextlib.suppress(OSError):
        earlier = sorted(p.name for p in folder.iterdir() if pattern.fullmatch(p.name))
        if earlier:
            logger.warning("%s: %d numbered file(s) of an earlier recording are there (%s); "
                           "this one overwrites those it reaches and leaves the others",
                           path, len(earlier), ", ".join(earlier[:3]) +
                           (", ..." if len(earlier) > 3 else ""))
