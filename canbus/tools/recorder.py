"""Record every frame to .log (candump -L), .asc, .blf (python-can's writers), .pcap or
.mcap (with the force samples, :meth:`Recorder.on_forces`; :mod:`canbus.tools.mcap_writer`).

A recording is a stream, written as it goes, as candump and ``can.logger`` write theirs:
the file exists under its own name from the start and is a complete, valid recording
after every write, which comes at least every :data:`FLUSH_S` (0.1 s). So whatever ends
the process (Ctrl-C, SIGTERM, kill -9, a crash), the file holds every frame received up
to the last write:

- .log and .pcap only grow, one whole batch of lines/records per write;
- .asc is written with its ``End TriggerBlock`` footer after every batch (the next batch
  overwrites it and ends with it again), so it is complete at every moment;
- .mcap: each write appends whole compressed chunks; closing adds the summary and the
  index (:mod:`canbus.tools.mcap_writer`);
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
goes on in ``run.001.log``, ``run.002.log``, ... (:func:`rotated_path`). The files and
their writers are :mod:`canbus.tools.segments`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import threading
import time
from collections import deque
from pathlib import Path
from typing import TYPE_CHECKING, cast

import can

from canbus.tools.segments import (
    DEFAULT_LOG_CHANNEL,
    FORMATS,
    CandumpLogWriter,
    Segment,
    check_channel_name,
    log_channel_name,
    open_segment,
)
from skin.errors import ConfigError, SkinError

if TYPE_CHECKING:
    from canbus.tools.mcap_messages import Placement
    from canbus.tools.mcap_writer import McapSegment
    from canbus.tools.sample_wire import ContactFields, Sample

logger = logging.getLogger(__name__)

__all__ = ["DEFAULT_LOG_CHANNEL", "CandumpLogWriter", "Recorder", "check_channel_name",
           "log_channel_name", "recording_format", "rotated_path"]


def recording_format(path: str | os.PathLike[str], *, field: str = "--record") -> str:
    """The suffix of a recording we can write; ConfigError for any other (no file touched)."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        known = ", ".join(FORMATS)
        raise ConfigError(field, f"unknown recording format {suffix or '(no suffix)'!r} "
                          f"of {os.fspath(path)!r}; use one of {known}")
    return suffix


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
                 rotate_bytes: int | None = None, rotate_s: float | None = None,
                 placements: list[Placement] | None = None) -> None:
        """``channel``: the interface name every frame of a .log gets (default ``can0``; an
        .mcap's frames without a channel of their own); .asc numbers channels, .blf and
        .pcap name none. ``placements``: where the patches sit (an .mcap's /tf_static)."""
        self.suffix = recording_format(path)
        if self.suffix == ".mcap":
            from canbus.tools.mcap_messages import require_mcap

            require_mcap()
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
        self._forces: deque[tuple[Sample, ContactFields | None]] = deque()
        self._placements = placements
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

    @property
    def takes_forces(self) -> bool:
        """Whether the format holds force samples (.mcap); the others hold the frames the
        force nodes published."""
        return self.suffix == ".mcap"

    def on_forces(self, frame: Sample, contact: ContactFields | None = None) -> None:
        """Queue a force sample (a ``HostManager.on_forces`` callback: an append, never a
        wait); written with the frames when the format holds samples. ``contact``: its
        contact summary's figures, where ``frame.contact`` does not hold them."""
        if self.takes_forces:
            self._forces.append((frame, contact))

    def _next_segment(self) -> Segment:
        path = rotated_path(self.path, len(self.files))
        try:
            segment = self._open(path)
        except OSError as err:
            if err.filename is not None or isinstance(err, SkinError):
                raise  # named already
            raise OSError(err.errno, err.strerror or str(err), str(path)) from err
        self.files.append(path)
        logger.info("recording to %s", path)
        return segment

    def _open(self, path: Path) -> Segment:
        if self.suffix == ".mcap":
            from canbus.tools.mcap_writer import McapSegment

            return McapSegment(path, self.channel, self._placements)
        return open_segment(path, self.suffix, self.channel)

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
                self._write_forces()
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

    def _write_forces(self) -> None:
        forces = self._forces
        if forces:
            write = cast("McapSegment", self._segment).write_forces
            for _ in range(len(forces)):
                write(*forces.popleft())

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
