"""Write a file so that it is either complete or absent: temp file, fsync, rename."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike[str]) -> Iterator[BinaryIO]:
    """Yield a binary file in the target's folder; rename it into place only on success."""
    target = Path(path)
    folder = target.parent if str(target.parent) else Path(".")
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=folder)
    except OSError as err:
        raise _naming(err, target) from err
    umask = os.umask(0)
    os.umask(umask)
    try:
        # mkstemp makes the file owner-only; give it the mode open() would.
        os.chmod(tmp_name, 0o666 & ~umask)
        with os.fdopen(fd, "wb") as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp_name, target)
    except BaseException as err:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp_name)
        if isinstance(err, OSError) and not isinstance(err, _NamedError):
            raise _naming(err, target) from err
        raise


class _NamedError(OSError):
    """An OS error of an atomic write, named by the file the user asked for."""


def _naming(err: OSError, target: Path) -> OSError:
    """The error as the user's file meets it (not the temporary file's name): a full disk
    says which file it could not write."""
    return _NamedError(err.errno, err.strerror or str(err), str(target))
