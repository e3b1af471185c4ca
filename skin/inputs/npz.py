"""``.npz`` archives of ``.npy`` arrays (datasets, reference forces), read without trust.

numpy's own ``np.load`` allocates whatever an array header declares before it reads a
byte of data (a header that promises 10^12 rows asks for terabytes), returns a bare
array for a ``.npy`` file saved under an ``.npz`` name, and raises a different exception
for each kind of damage. :func:`read_npz` instead:

- refuses a file that is not a zip archive, saying what it is (a ``.npy``, empty, ...);
- takes at most :data:`MAX_MEMBERS` members, each a ``.npy`` named once;
- reads each member's header first: a plain numeric, boolean or text dtype (no Python
  objects: that would be pickle; no structured records), at most :data:`MAX_DIMS`
  dimensions, and a declared size that is exactly what the member holds and within the
  memory budget (:mod:`skin.inputs.budget`), all before allocating;
- then reads the data into the array it allocated, refusing a member cut short.

Every failure is one message naming the file and the member, made by the caller's
``fail`` (a DatasetError, a ReferenceFileError).
"""

from __future__ import annotations

import math
import os
import zipfile
from collections.abc import Callable
from typing import IO, Any

import numpy as np

from skin.inputs.budget import memory_budget, size_text

MAX_MEMBERS = 64
MAX_DIMS = 8
NPY_MAGIC = b"\x93NUMPY"
ZIP_MAGICS = (b"PK\x03\x04", b"PK\x05\x06")
_KINDS = frozenset("fiubU")

Fail = Callable[[str], Exception]


def _what_it_is(head: bytes) -> str:
    if not head:
        return "an empty file"
    if head.startswith(NPY_MAGIC):
        return "a single .npy array (np.save), not an .npz archive (np.savez)"
    return "not an .npz (zip) archive"


def read_npz(path: str | os.PathLike[str], fail: Fail) -> dict[str, np.ndarray]:
    """Every array of the archive at ``path``, by name without ``.npy``."""
    source = os.fspath(path)
    try:
        with open(source, "rb") as handle:
            head = handle.read(8)
            size = os.fstat(handle.fileno()).st_size
    except FileNotFoundError as err:
        raise fail("no such file") from err
    except IsADirectoryError as err:
        raise fail("is a folder, not a file") from err
    except OSError as err:
        raise fail(f"cannot read: {err.strerror}") from err
    if not head.startswith(ZIP_MAGICS):
        raise fail(_what_it_is(head))
    try:
        with zipfile.ZipFile(source) as archive:
            return _members(archive, size)
    except _RefusedError as err:
        raise fail(str(err)) from None
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, RuntimeError,
            NotImplementedError, ValueError, KeyError, UnicodeError, MemoryError) as err:
        raise fail(f"not a readable .npz archive ({_one_line(err)})") from err


class _RefusedError(Exception):
    """What is wrong with the archive (the caller's ``fail`` makes its error of it)."""


def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split())
    return f"{type(err).__name__}: {text}" if text else type(err).__name__


def _members(archive: zipfile.ZipFile, file_size: int) -> dict[str, np.ndarray]:
    infos = archive.infolist()
    if len(infos) > MAX_MEMBERS:
        raise _RefusedError(f"{len(infos)} members, more than the {MAX_MEMBERS} allowed")
    names = [info.filename for info in infos]
    for name in names:
        if not name.endswith(".npy"):
            raise _RefusedError(f"member {name!r} is not a .npy array")
        if names.count(name) > 1:
            raise _RefusedError(f"member {name!r} appears twice")
    declared = sum(info.file_size for info in infos)
    budget = memory_budget()
    if declared > budget:
        raise _RefusedError(f"its members declare {size_text(declared)} in all, more than "
                            f"the memory budget of {size_text(budget)} (the file has "
                            f"{size_text(file_size)})")
    out: dict[str, np.ndarray] = {}
    for info in infos:
        name = info.filename[:-4]
        with archive.open(info) as member:
            out[name] = _read_member(member, info.file_size, name)
    return out


def _read_member(member: IO[bytes], member_size: int, name: str) -> np.ndarray:
    try:
        version = np.lib.format.read_magic(member)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(member)
        elif version in ((2, 0), (3, 0)):
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(member)
        else:
            raise ValueError(f"unknown .npy version {version}")
    except (ValueError, EOFError, SyntaxError, TypeError) as err:
        raise _RefusedError(f"{name}: not a .npy array ({_one_line(err)})") from err
    header = member.tell()
    _check_header(shape, dtype, name)
    nbytes = math.prod(shape) * dtype.itemsize
    if nbytes != member_size - header:
        raise _RefusedError(f"{name}: its header declares shape {tuple(shape)} of {dtype.str} "
                            f"({size_text(nbytes)}) but the member holds "
                            f"{size_text(member_size - header)}")
    array = np.empty(shape, dtype=dtype, order="F" if fortran else "C")
    view = array.reshape(-1, order="A").view(np.uint8).data
    done = 0
    while done < nbytes:
        got = member.readinto(view[done:])  # type: ignore[attr-defined]
        if not got:
            raise _RefusedError(f"{name}: cut short at {done} of {nbytes} data bytes")
        done += got
    return array


def _check_header(shape: Any, dtype: np.dtype[Any], name: str) -> None:
    if dtype.hasobject:
        raise _RefusedError(f"{name}: holds Python objects (pickle), never loaded")
    if dtype.names is not None or dtype.subdtype is not None or dtype.kind not in _KINDS:
        raise _RefusedError(f"{name}: dtype {dtype.str} is not a number, boolean or text type")
    if len(shape) > MAX_DIMS:
        raise _RefusedError(f"{name}: {len(shape)} dimensions, more than {MAX_DIMS}")
