"""Where results go: regular files only, and errors that name the user's path.

Every file canskin writes (``--json``, ``-o``, ``--record``, ``--png``, ``--truth``, ...)
goes through :func:`check_output` first: an existing FIFO, device node, socket or folder
is refused (writing there would replace it, or block, or lose the result), as is a
folder that does not exist or a read-only file. Files are then written beside their
target under a hidden temporary name (:func:`create_beside`) and renamed into place
(:func:`put_in_place`), so an existing file is replaced only by a complete new one (a
result) or one that already holds its first write (a recording); every OSError on the
way becomes an :class:`~skin.errors.OutputError` that names the user's path, never the
temporary name.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
from collections.abc import Callable
from pathlib import Path

from skin.errors import OutputError, SkinError

_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
          (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"))


def _kind(mode: int) -> str:
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def refusal(path: str | os.PathLike[str]) -> str | None:
    """Why results cannot go to ``path``, or None when they can."""
    text = os.fspath(path)
    if not text:
        return "an empty path"
    target = Path(text)
    try:
        info = target.stat()
    except FileNotFoundError:
        info = None
    except OSError as err:
        return f"cannot be looked at ({err.strerror})"
    if info is not None:
        if not stat.S_ISREG(info.st_mode):
            return f"is {_kind(info.st_mode)}; results go to regular files only"
        if not os.access(target, os.W_OK):
            return "is read-only"
    folder = target.parent
    try:
        folder_info = folder.stat()
    except FileNotFoundError:
        return f"its folder {os.fspath(folder)!r} does not exist"
    except OSError as err:
        return f"its folder {os.fspath(folder)!r} cannot be looked at ({err.strerror})"
    if not stat.S_ISDIR(folder_info.st_mode):
        return f"{os.fspath(folder)!r} is not a folder"
    return None


def check_output(path: str | os.PathLike[str]) -> Path:
    """``path`` as a Path; OutputError when results cannot go there."""
    why = refusal(path)
    if why is not None:
        raise OutputError(f"cannot write {os.fspath(path)!r}: {why}")
    return Path(path)


def check_writable(path: str | os.PathLike[str]) -> None:
    """OutputError when results cannot go to ``path``, found before the work that makes them:
    a new file is made beside it and removed (a read-only folder, a full inode table)."""
    fd, tmp = create_beside(path)
    os.close(fd)
    discard(tmp)


def write_error(path: str | os.PathLike[str], err: OSError) -> OutputError:
    """``err`` (raised while writing ``path`` or its temporary file) naming ``path``."""
    reason = err.strerror or str(err)
    return OutputError(f"cannot write {os.fspath(path)!r}: {reason}")


def create_beside(path: str | os.PathLike[str], suffix: str = ".tmp") -> tuple[int, str]:
    """A new file beside ``path``, under a hidden temporary name ending in ``suffix``, open
    for reading and writing (mode as ``open()`` gives): (its descriptor, its name)."""
    target = check_output(path)
    for attempt in range(100):
        tmp = os.fspath(target.with_name(f".{target.name}.{os.getpid()}.{attempt}{suffix}"))
        try:
            fd = os.open(tmp, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o666)
        except FileExistsError:
            continue
        except OSError as err:
            raise write_error(path, err) from err
        return fd, tmp
    raise OutputError(f"cannot write {os.fspath(path)!r}: no free temporary name beside it")


RESERVE_BYTES = 64 << 10
"""What a stream (a recording) proves it can write before it replaces an existing file."""


def reserve(fd: int) -> None:
    """Prove the file system has room for the first writes of the stream open on ``fd``:
    allocate :data:`RESERVE_BYTES` past its end, then give them back (a file system that
    cannot allocate ahead is taken at its word). OSError (ENOSPC) when there is none."""
    end = os.fstat(fd).st_size
    try:
        os.posix_fallocate(fd, end, RESERVE_BYTES)
    except OSError as err:
        if err.errno not in (errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):
            raise
    os.ftruncate(fd, end)


def put_in_place(tmp: str, path: str | os.PathLike[str]) -> None:
    """Rename ``tmp`` over ``path`` (checked again: nothing replaced it meanwhile)."""
    why = refusal(path)
    if why is not None:
        discard(tmp)
        raise OutputError(f"cannot write {os.fspath(path)!r}: {why}")
    try:
        os.replace(tmp, path)
    except OSError as err:
        discard(tmp)
        raise write_error(path, err) from err


def create_in_place(path: str | os.PathLike[str], write_header: Callable[[int], object]) -> int:
    """A stream's file at ``path``: created beside it, ``write_header(fd)`` called, room for
    the first writes proved (:func:`reserve`), then renamed over ``path``, so an existing
    file is replaced only by a stream that could be written; its descriptor. An OSError as
    one line naming ``path``, and nothing left behind."""
    fd, tmp = create_beside(path)
    try:
        write_header(fd)
        reserve(fd)
    except BaseException as err:
        os.close(fd)
        discard(tmp)
        if isinstance(err, OSError) and not isinstance(err, SkinError):
            raise write_error(path, err) from err
        raise
    try:
        put_in_place(tmp, path)
    except BaseException:
        os.close(fd)
        raise
    return fd


def discard(tmp: str) -> None:
    with contextlib.suppress(OSError):
        os.unlink(tmp)
