"""Write a file so that it is either complete or absent: temp file, fsync, rename.

The target is checked first (:func:`skin.inputs.outputs.check_output`: a regular file or
nothing, in a folder that exists) and every error names it, never the temporary file.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from skin.errors import SkinError
from skin.inputs.outputs import create_beside, discard, put_in_place, write_error


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike[str]) -> Iterator[BinaryIO]:
    """Yield a binary file in the target's folder; rename it into place only on success."""
    fd, tmp_name = create_beside(path)
    with _in_place_on_success(tmp_name, path), os.fdopen(fd, "wb") as handle:
        yield handle
        handle.flush()
        os.fsync(handle.fileno())


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """A temporary path beside ``path`` with its suffix (for writers that take a path and
    pick the format by its suffix), renamed onto ``path`` only if the block succeeds."""
    fd, tmp_name = create_beside(path, suffix=f".tmp{Path(path).suffix}")
    os.close(fd)
    with _in_place_on_success(tmp_name, path):
        yield Path(tmp_name)


@contextlib.contextmanager
def _in_place_on_success(tmp_name: str, path: str | os.PathLike[str]) -> Iterator[None]:
    """Rename ``tmp_name`` onto ``path`` when the block succeeds; else remove it, an OS
    error named by the user's path."""
    try:
        yield
    except OSError as err:
        discard(tmp_name)
        if isinstance(err, SkinError):
            raise
        raise write_error(path, err) from err
    except BaseException:
        discard(tmp_name)
        raise
    put_in_place(tmp_name, path)
