"""Read recordings back, checked frame by frame (:class:`Recording`).

Readers are python-can's (``CanutilsLogReader``, ``ASCReader``, ``BLFReader``) and our
``canbus.tools.pcap.PcapReader``. python-can's readers skip what they do not understand and
stop quietly at a cut, so each is wrapped with the checks that make a damaged file an
error, :class:`~skin.errors.RecordingError`, naming the first bad frame (1-based) and,
for text files, its line. Nothing from that frame on is yielded, so nothing past it is
replayed (:mod:`canbus.tools.replay`):

- every frame: a valid identifier, a data length that matches the DLC (0..8, or a CAN FD
  length), a finite timestamp;
- .log and .asc: UTF-8, every line ends with a newline (a cut line is a truncated file);
  every .log line is a ``candump -L`` frame; every .asc frame line yields a frame; an
  .asc ends with ``End TriggerBlock``;
- .blf: the file is as long as its header says; parse and zlib errors; object and
  container sizes bounded (``canbus.tools.blfread``: no endless loop, no decompression
  bomb);
- .pcap: see ``canbus.tools.pcap``; a pcapng file (dumpcap's default, also under a .pcap
  name): see ``canbus.tools.pcapng``;
- .mcap: its /can/frames and /can/fd_frames in file order (``canbus.tools.mcap_reader``):
  the MCAP magic, chunk CRCs, those topics' schemas, every message decodes, a footer at
  the end (a file without one is cut short: its writer did not finish).

A .log cut exactly at the end of a line is indistinguishable from a shorter recording.

``partial=True`` reads a recording whose writer was killed (kill -9, a power cut): a bad
frame at the very end of the file, where such a cut lands (a line without its newline, an
.asc without ``End TriggerBlock``, a cut pcap record, a cut last .blf container, a .blf
shorter than its header says), ends the recording quietly, and :attr:`Recording.cut`
says what was dropped; a bad frame anywhere before the end is still an error.
"""

from __future__ import annotations

import io
import logging
import math
import os
import re
import struct
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, BinaryIO, TextIO, cast

import can
from can.io.blf import BLFParseError

from canbus.tools.blfread import BoundedBLFReader
from canbus.tools.mcap_reader import McapFrames
from canbus.tools.pcap import FD_LENGTHS, PcapReader
from canbus.tools.pcapng import SECTION_HEADER, PcapngReader
from skin.errors import ConfigError, RecordingError

logger = logging.getLogger(__name__)

__all__ = ["READERS", "Recording", "RecordingError", "recording_reader"]

READERS: dict[str, Callable[..., can.io.generic.MessageReader]] = {
    ".log": can.CanutilsLogReader, ".asc": can.ASCReader, ".blf": BoundedBLFReader,
    ".pcap": PcapReader, ".pcapng": PcapngReader, ".mcap": McapFrames,
}
_LOG_LINE = re.compile(
    r"\(\d+\.\d+\) \S+ (?:[0-9A-Fa-f]{3}|[0-9A-Fa-f]{8})#"
    r"(?:R\d?|#[0-9A-Fa-f](?:[0-9A-Fa-f]{2})*|(?:[0-9A-Fa-f]{2})*)(?: [RT])?\r?\n")
_ASC_FRAME = re.compile(r"\s*\d+\.\d+\s+(?:\d+\s+[0-9A-Fa-f]+x?\s+(?:Rx|Tx)\s|\d+\s+ErrorFrame"
                        r"|CANFD\s+\d+\s+(?:Rx|Tx)\s)")
_READ_ERRORS = (ValueError, IndexError, KeyError, struct.error, zlib.error, BLFParseError,
                UnicodeDecodeError, ArithmeticError, TypeError, AttributeError, EOFError)
MAX_LINE = 1 << 16
"""The longest line a text recording may have (a candump -L line is under 300 bytes)."""


def recording_reader(path: str | os.PathLike[str], *, field: str = "FILE") -> str:
    """The suffix of a recording we can read; ConfigError for any other (no file opened)."""
    suffix = Path(path).suffix.lower()
    if suffix not in READERS:
        raise ConfigError(field, f"unknown recording format {suffix or '(no suffix)'!r} of "
                          f"{os.fspath(path)!r}; use one of {', '.join(READERS)}")
    return suffix


def _read_to_end(file: BinaryIO) -> bool:
    """Whether ``file`` has been read to its end (closed: its reader finished it)."""
    return file.closed or file.tell() >= os.fstat(file.fileno()).st_size


class _Lines:
    """A text recording line by line for python-can's reader, with the checks it lacks."""

    def __init__(self, path: Path, suffix: str, frames: Callable[[], int]) -> None:
        self._file: BinaryIO = path.open("rb")
        self._source = str(path)
        self._suffix = suffix
        self._frames = frames  # how many frames the reader has yielded so far
        self.line = 0
        self._frame_line: tuple[int, int] | None = None  # (line, frames before it)
        self._last = ""

    def __iter__(self) -> _Lines:
        return self

    def _fail(self, problem: str, line: int | None = None) -> RecordingError:
        return RecordingError(self._source, self._frames() + 1,
                              f"line {line or self.line}: {problem}")

    def _check_skipped(self) -> None:
        if self._frame_line is not None and self._frames() == self._frame_line[1]:
            raise self._fail("a frame line that does not parse", self._frame_line[0])
        self._frame_line = None

    def __next__(self) -> str:
        self._check_skipped()
        raw = self._file.readline(MAX_LINE + 1)
        if len(raw) > MAX_LINE:
            self.line += 1
            raise self._fail(f"longer than {MAX_LINE} bytes: not a recording's line")
        if not raw:
            if self._suffix == ".asc" and self._last.strip().lower() != "end triggerblock":
                raise RecordingError(self._source, self._frames() + 1,
                                     "the file ends here without 'End TriggerBlock' "
                                     "(truncated)")
            raise StopIteration
        self.line += 1
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as err:
            raise self._fail(f"not UTF-8 text ({err.reason} at byte {err.start})") from err
        if not text.endswith("\n"):
            raise self._fail("cut short before its end of line (truncated file)")
        if text.strip():
            self._last = text
            if self._suffix == ".log" and not _LOG_LINE.fullmatch(text):
                raise self._fail(f"not a candump -L frame: {text.strip()[:60]!r}")
            if self._suffix == ".asc" and _ASC_FRAME.match(text):
                self._frame_line = (self.line, self._frames())
        return text

    def at_end(self) -> bool:
        """Whether everything has been read: the line that failed was the last."""
        return _read_to_end(self._file)

    def close(self) -> None:
        self._file.close()

    @property
    def closed(self) -> bool:
        return self._file.closed


class _CountingFile(io.RawIOBase):
    """A binary file that notes whether a read came back short: a cut last record."""

    def __init__(self, path: Path) -> None:
        super().__init__()
        self._file = path.open("rb")
        self.name = str(path)
        self.short = False

    def readable(self) -> bool:
        return True

    def read(self, size: int = -1) -> bytes:
        data = self._file.read(size)
        if size is not None and size > 0 and 0 < len(data) < size:
            self.short = True
        return data

    def readinto(self, buffer: Any) -> int:
        data = self.read(len(buffer))
        buffer[:len(data)] = data
        return len(data)

    def at_end(self) -> bool:
        return self.short or _read_to_end(self._file)

    def close(self) -> None:
        self._file.close()
        super().close()


class Recording:
    """A recording opened and checked: iterate it for its messages (once per instance).

    ``partial``: a bad frame at the very end of the file (a cut tail) ends the recording
    instead of raising; :attr:`cut` then names it.
    """

    def __init__(self, path: str | os.PathLike[str], *, partial: bool = False) -> None:
        self.path = Path(path)
        self.suffix = recording_reader(path)
        self.partial = partial
        self.frames = 0
        self.cut: RecordingError | None = None
        self._lines: _Lines | None = None
        self._binary: _CountingFile | None = None
        self._plain: BinaryIO | None = None
        source = str(self.path)
        try:
            if self.suffix == ".mcap":
                from canbus.tools.mcap_messages import require_mcap

                require_mcap("FILE")
                self._plain = self.path.open("rb")
                self._reader: can.io.generic.MessageReader = McapFrames(self._plain)
            elif self.suffix in (".log", ".asc"):
                self._lines = _Lines(self.path, self.suffix, lambda: self.frames)
                self._reader = READERS[self.suffix](cast(TextIO, self._lines))
            elif self.suffix == ".pcap" and _is_pcapng(self.path):  # dumpcap's default format
                self._reader = PcapngReader(source)
            else:
                self._binary = _CountingFile(self.path)
                self._reader = READERS[self.suffix](cast(BinaryIO, self._binary))
        except RecordingError:
            self._close_files()
            raise
        except FileNotFoundError as err:
            raise RecordingError(source, None, "no such file") from err
        except IsADirectoryError as err:
            raise RecordingError(source, None, "is a folder, not a recording") from err
        except OSError as err:
            self._close_files()
            raise RecordingError(source, None, f"cannot read: {err.strerror}") from err
        except _READ_ERRORS as err:
            self._close_files()
            raise RecordingError(source, None, f"not a {self.suffix} file: {err}") from err

    def __enter__(self) -> Recording:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._reader.stop()
        self._close_files()

    def _close_files(self) -> None:
        for file in (self._lines, self._binary, self._plain):
            if file is not None:
                file.close()

    def _at_end(self) -> bool:
        if self._lines is not None:
            return self._lines.at_end()
        if self._plain is not None:
            return _read_to_end(self._plain)
        return self._binary is not None and self._binary.at_end()

    def __iter__(self) -> Iterator[can.Message]:
        try:
            yield from self._checked()
        except RecordingError as err:
            if not (self.partial and self._at_end()):
                raise
            self.cut = err
            logger.warning("%s; the %d whole frames before it are kept", err, self.frames)

    def _checked(self) -> Iterator[can.Message]:
        source = str(self.path)
        messages = iter(self._reader)
        while True:
            try:
                msg = next(messages)
            except StopIteration:
                break
            except RecordingError:
                raise
            except _READ_ERRORS as err:
                where = f"line {self._lines.line}: " if self._lines is not None else ""
                raise RecordingError(source, self.frames + 1,
                                     f"{where}{type(err).__name__}: {err}") from err
            problem = _problem(msg)
            if problem is not None:
                where = f"line {self._lines.line}: " if self._lines is not None else ""
                raise RecordingError(source, self.frames + 1, where + problem)
            self.frames += 1
            yield msg
        if self.suffix == ".blf":
            self._check_blf_end(source)

    def _check_blf_end(self, source: str) -> None:
        """A .blf shorter than its header says, or cut inside its last container."""
        expected = cast(can.BLFReader, self._reader).file_size
        actual = self.path.stat().st_size
        if actual < expected:
            raise RecordingError(source, self.frames + 1, f"the file ends here, at {actual}"
                                 f" of the {expected} bytes its header promises (truncated)")
        if self._binary is not None and self._binary.short:
            raise RecordingError(source, self.frames + 1, "the file ends inside its last "
                                 f"container, at byte {actual} (truncated)")


def _is_pcapng(path: Path) -> bool:
    try:
        with path.open("rb") as handle:
            head = handle.read(4)
    except OSError:
        return False
    return len(head) == 4 and struct.unpack("<I", head)[0] == SECTION_HEADER


def _problem(msg: can.Message) -> str | None:
    """What is wrong with a message read from a file, or None."""
    if not math.isfinite(msg.timestamp):
        return f"timestamp {msg.timestamp} is not finite"
    if msg.is_error_frame:
        return None
    limit = 0x1FFF_FFFF if msg.is_extended_id else 0x7FF
    if not 0 <= msg.arbitration_id <= limit:
        return f"identifier 0x{msg.arbitration_id:X} is out of range"
    length = len(msg.data)
    if msg.is_fd:
        return None if length in FD_LENGTHS else f"CAN FD length {length} is not an FD length"
    if msg.is_remote_frame:
        return None if 0 <= msg.dlc <= 8 else f"remote frame DLC {msg.dlc} is above 8"
    if length > 8:
        return f"{length} data bytes in a classic CAN frame"
    if msg.dlc != length:
        return f"DLC {msg.dlc} but {length} data bytes"
    return None
