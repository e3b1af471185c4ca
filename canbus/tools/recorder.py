"""Record every frame to .log (candump -L), .asc, .blf (python-can's writers) or .pcap.

:class:`Recorder` is a ``can.Listener`` whose receive side only appends the message to
its own unbounded deque; a thread wakes every 10 ms and writes out what has arrived. So
a slow view, a slow disk or a burst never costs a frame: the deque grows instead and is
written out, and the receive thread is not woken up per frame.
The file is written through ``skin.atomic.atomic_write``: it appears under its name only
when :meth:`Recorder.stop` has written, flushed and synced every queued frame (Ctrl-C
included); :meth:`Recorder.abort` and any writer error leave no file behind.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import socket
import threading
from collections import deque
from contextlib import ExitStack
from pathlib import Path
from typing import IO, Any, BinaryIO, TextIO, cast

import can
from can.io.generic import MessageWriter

from canbus.tools.pcap import PcapWriter
from skin.atomic import atomic_write
from skin.errors import ConfigError

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
_POLL_S = 0.01


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


class _Borrowed(io.RawIOBase):
    """The atomic file as the writer sees it: its close() only flushes, the owner closes."""

    def __init__(self, handle: BinaryIO) -> None:
        super().__init__()
        self._handle = handle

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def write(self, data: Any) -> int:
        return self._handle.write(data)

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        return self._handle.seek(offset, whence)

    def tell(self) -> int:
        return self._handle.tell()

    def flush(self) -> None:
        if not self.closed and not self._handle.closed:
            self._handle.flush()

    def close(self) -> None:
        self.flush()
        super().close()


class Recorder(can.Listener):
    """Queues every received frame and writes it to ``path`` in a thread of its own."""

    def __init__(self, path: str | os.PathLike[str], *, channel: str | None = None) -> None:
        """``channel``: the interface name every frame of a .log gets (default ``can0``);
        .asc numbers channels, .blf and .pcap name none."""
        suffix = recording_format(path)
        self.path = Path(path)
        self.received = 0
        self.written = 0
        self.error: BaseException | None = None
        self.saved: Path | None = None
        self._finished = False
        self._pending: deque[can.Message] = deque()
        self._stopping = threading.Event()
        self._stack = ExitStack()
        handle = self._stack.enter_context(atomic_write(self.path))
        raw = _Borrowed(handle)
        file: IO[Any] = io.TextIOWrapper(cast(BinaryIO, raw), encoding="utf-8", newline="\n") \
            if suffix in _TEXT else cast(BinaryIO, raw)
        kwargs = {} if channel is None or suffix != ".log" else {"channel": channel}
        self._writer = WRITERS[suffix](cast(TextIO, file), **kwargs)  # type: ignore[arg-type]
        self._thread = threading.Thread(target=self._drain, name="recorder", daemon=True)
        self._thread.start()

    @property
    def pending(self) -> int:
        """Frames received but not yet handed to the writer."""
        return len(self._pending)

    def on_message_received(self, msg: can.Message) -> None:
        self._pending.append(msg)  # atomic; no lock, no wake-up per frame
        self.received += 1

    def _drain(self) -> None:
        """Every few milliseconds, write out whatever has arrived (batches, few GIL hand-offs)."""
        pending, write = self._pending, self._writer.on_message_received
        try:
            while True:
                stopping = self._stopping.wait(_POLL_S)
                while pending:
                    write(pending.popleft())
                    self.written += 1
                if stopping:
                    return
        except BaseException as err:  # reported by stop(); the rest is abandoned
            self.error = err

    def stop(self) -> None:
        """Write out everything queued, flush, sync and rename into place (idempotent).

        python-can's ``Notifier.stop()`` calls it; afterwards :attr:`saved` is the path.
        """
        if self._finished:
            return
        self._finished = True
        self._stopping.set()
        self._thread.join()
        if self.error is not None:
            self._discard()
            raise OSError(f"recording to {self.path} failed: {self.error}") from self.error
        try:
            self._writer.stop()
        except BaseException:
            self._discard()
            raise
        self._stack.close()
        self.saved = self.path

    def abort(self) -> None:
        """Stop without keeping the file (idempotent)."""
        if self._finished:
            return
        self._finished = True
        self._stopping.set()
        self._thread.join()
        self._discard()

    def _discard(self) -> None:
        self._stack.__exit__(RuntimeError, RuntimeError("recording discarded"), None)
