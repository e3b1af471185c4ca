"""Reference forces: what a calibration rig (or the simulator) says pressed on each patch.

The format (docs/calibrate.md) is a CSV file with a header, or an .npz of 1-D arrays with
the same names:

- ``time_s`` (seconds, any clock) and/or ``sync`` (the SYNC counter the sample answers,
  1..240; 0 in every row: the SYNCs carried none): when the sample was taken; at least
  one of them;
- ``node_id``: the patch (1..127);
- ``taxel`` (0..8), one row per taxel and all nine per sample; or ``x_m``, ``y_m``: a
  contact point in the patch frame (taxel k sits at ((k % 3 - 1)·pitch, (k // 3 - 1)·pitch))
  whose force is spread over the taxels (:func:`spread_point`); rows of one sample add;
- ``fx_N``, ``fy_N``, ``fz_N``: the force in newtons (Fz > 0 presses into the skin).

Rows with the same ``node_id``, ``time_s`` and ``sync`` are one sample. A taxel-form
sample that lacks a taxel is incomplete: it is counted and left out, never filled in. A
malformed file raises :class:`~skin.errors.ReferenceFileError` naming the file and the
row (CSV: the line number, the header being line 1; .npz: the 1-based index).
"""

from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from numpy.typing import NDArray

from skin.constants import DEFAULT_CONSTANTS, TAXELS_PER_PATCH
from skin.errors import ReferenceFileError
from skin.inputs import fields
from skin.inputs.budget import memory_budget, size_text
from skin.inputs.npz import read_npz
from skin.inputs.outputs import create_beside, discard, put_in_place, write_error

F64 = NDArray[np.float64]
FORCE_COLUMNS = ("fx_N", "fy_N", "fz_N")
TAXEL_COLUMNS = ("time_s", "sync", "node_id", "taxel", *FORCE_COLUMNS)
"""The columns :class:`ReferenceWriter` writes (the taxel form, with both keys)."""
KNOWN_COLUMNS = frozenset({"time_s", "sync", "node_id", "taxel", "x_m", "y_m", *FORCE_COLUMNS})
CSV_MEMORY_FACTOR = 20
"""Bytes of memory one byte of CSV takes once split into Python strings (about)."""
SYNC_MAX = 255
"""SYNC counter bytes a reference may name (CiA 301 sends 1..240; 0 means none)."""


@dataclass(frozen=True)
class ReferenceSamples:
    """Reference samples, sorted by node-ID, then time (without a time: file order).

    ``time_s`` is NaN and ``sync`` 0 where the file has no such column.
    """

    source: str
    node_id: NDArray[np.int64]  # (n,)
    time_s: F64  # (n,)
    sync: NDArray[np.int64]  # (n,)
    force_N: F64  # (n, 9, 3)
    row: NDArray[np.int64]  # (n,) the first row of each sample, for messages
    has_time: bool
    has_sync: bool
    form: str  # "taxel" or "point"
    rows: int  # rows read
    incomplete: dict[int, int]  # node-ID -> taxel-form samples that lack a taxel (left out)

    def of_node(self, node_id: int) -> NDArray[np.intp]:
        """Indexes of one patch's samples, in time order."""
        return np.flatnonzero(self.node_id == node_id)

    @property
    def nodes(self) -> tuple[int, ...]:
        return tuple(int(n) for n in np.unique(self.node_id))


def spread_point(x_m: F64, y_m: F64, force_N: F64,
                 pitch_m: float = DEFAULT_CONSTANTS.taxel_pitch_m) -> F64:
    """Point forces ``(n, 3)`` at ``(n,)`` contact points -> ``(n, 9, 3)`` taxel forces.

    Bilinear weights over the four taxel centres around the point (a point on a centre
    puts everything on that taxel; midway between two, half on each); a point between
    the outer centres and the patch edge belongs to the edge taxels. Weights sum to one,
    so the total force is kept exactly. Points must lie on the patch (|x|, |y| <= 1.5
    pitches): the caller checks.
    """
    u = np.clip(np.asarray(x_m, np.float64) / pitch_m + 1.0, 0.0, 2.0)  # column coordinate
    v = np.clip(np.asarray(y_m, np.float64) / pitch_m + 1.0, 0.0, 2.0)  # row coordinate
    c0 = np.minimum(np.floor(u), 1.0).astype(np.intp)
    r0 = np.minimum(np.floor(v), 1.0).astype(np.intp)
    fu, fv = u - c0, v - r0
    out = np.zeros((u.size, TAXELS_PER_PATCH, 3))
    rows = np.arange(u.size)
    f = np.asarray(force_N, np.float64).reshape(-1, 3)
    for dr, dc, w in ((0, 0, (1 - fv) * (1 - fu)), (0, 1, (1 - fv) * fu),
                      (1, 0, fv * (1 - fu)), (1, 1, fv * fu)):
        taxel = 3 * (r0 + dr) + (c0 + dc)
        np.add.at(out, (rows, taxel), w[:, None] * f)
    return out


def read_reference(path: str | os.PathLike[str], *,
                   pitch_m: float = DEFAULT_CONSTANTS.taxel_pitch_m) -> ReferenceSamples:
    """Read and check a reference file (.csv or .npz); see the module docstring."""
    source = os.fspath(path)
    suffix = Path(path).suffix.lower()
    if suffix == ".csv":
        columns, lines = _read_csv(source)
    elif suffix == ".npz":
        columns, lines = _read_npz(source)
    else:
        raise ReferenceFileError(source, None, f"unknown format {suffix or '(no suffix)'!r}; "
                                 "use .csv or .npz")
    return _samples(source, columns, lines, pitch_m)


def _read_csv(source: str) -> tuple[dict[str, list[str]], NDArray[np.int64]]:
    try:
        size = os.stat(source).st_size
        if size * CSV_MEMORY_FACTOR > memory_budget():
            raise ReferenceFileError(source, None, f"{size_text(size)} of CSV would need "
                                     f"about {size_text(size * CSV_MEMORY_FACTOR)} of memory, "
                                     f"more than the budget of {size_text(memory_budget())}")
        with open(source, encoding="utf-8", newline="") as handle:
            text = handle.read()
    except FileNotFoundError as err:
        raise ReferenceFileError(source, None, "no such file") from err
    except UnicodeDecodeError as err:
        raise ReferenceFileError(source, None, f"not UTF-8 text ({err.reason} at byte "
                                 f"{err.start})") from err
    except IsADirectoryError as err:
        raise ReferenceFileError(source, None, "is a folder, not a file") from err
    except OSError as err:
        raise ReferenceFileError(source, None, f"cannot read: {err.strerror}") from err
    if not text:
        raise ReferenceFileError(source, None, "empty file: expected a header line")
    reader = csv.reader(io.StringIO(text), strict=True)
    try:
        header = [name.strip() for name in next(reader)]
        data: list[list[str]] = []
        numbers: list[int] = []
        for fields in reader:
            if not fields:
                continue  # a blank line
            if len(fields) != len(header):
                raise ReferenceFileError(source, reader.line_num, f"{len(fields)} fields, the "
                                         f"header names {len(header)}")
            data.append(fields)
            numbers.append(reader.line_num)
    except csv.Error as err:
        raise ReferenceFileError(source, reader.line_num, f"not valid CSV ({err})") from err
    if not text.endswith("\n"):
        raise ReferenceFileError(source, reader.line_num,
                                 "cut short before its end of line (truncated file)")
    _check_header(source, header)
    columns = {name: [fields[k] for fields in data] for k, name in enumerate(header)}
    return columns, np.array(numbers, dtype=np.int64)


def _check_header(source: str, header: list[str]) -> None:
    for name in header:
        if name not in KNOWN_COLUMNS:
            raise ReferenceFileError(source, 1, f"unknown column {name!r}; known: "
                                     f"{', '.join(sorted(KNOWN_COLUMNS))}")
    if len(set(header)) != len(header):
        raise ReferenceFileError(source, 1, "a column is named twice")


def _read_npz(source: str) -> tuple[dict[str, Any], NDArray[np.int64]]:
    arrays = read_npz(source, lambda problem: ReferenceFileError(source, None, problem))
    _check_header(source, list(arrays))
    lengths = {a.shape for a in arrays.values()}
    if any(a.ndim != 1 for a in arrays.values()) or len(lengths) > 1:
        raise ReferenceFileError(source, None, "every array must be 1-D and of one length, got "
                                 + ", ".join(f"{k} {a.shape}" for k, a in arrays.items()))
    n = next(iter(lengths))[0] if lengths else 0
    return arrays, np.arange(1, n + 1, dtype=np.int64)


def _column(source: str, columns: dict[str, Any], lines: NDArray[np.int64], name: str,
            kind: type) -> NDArray[Any]:
    """One column as float64 or int64, every value checked (finite numbers)."""
    values = columns[name]
    try:
        out = np.asarray(values, dtype=np.float64)
    except (ValueError, TypeError):
        out = None
    if out is None or not np.all(np.isfinite(out)):
        for k, value in enumerate(values):
            try:
                number = float(value)
            except (ValueError, TypeError):
                raise ReferenceFileError(source, int(lines[k]), f"{name}: not a number: "
                                         f"{value!r}") from None
            if not math.isfinite(number):
                raise ReferenceFileError(source, int(lines[k]), f"{name}: must be finite, "
                                         f"got {value!r}")
    assert out is not None
    if kind is int:
        whole = (out == np.rint(out)) & (np.abs(out) <= 2**53)
        if not np.all(whole):
            k = int(np.flatnonzero(~whole)[0])
            raise ReferenceFileError(source, int(lines[k]), f"{name}: must be a whole number, "
                                     f"got {values[k]!r}")
        return out.astype(np.int64)
    return out


def _in_range(source: str, lines: NDArray[np.int64], name: str, values: NDArray[Any],
              low: float, high: float, what: str) -> None:
    bad = (values < low) | (values > high)
    if np.any(bad):
        k = int(np.flatnonzero(bad)[0])
        raise ReferenceFileError(source, int(lines[k]), f"{name}: {values[k].item()!r} is not "
                                 f"{what}")


def _samples(source: str, columns: dict[str, Any], lines: NDArray[np.int64],
             pitch_m: float) -> ReferenceSamples:
    names = set(columns)
    has_time, has_sync = "time_s" in names, "sync" in names
    if not (has_time or has_sync):
        raise ReferenceFileError(source, 1, "needs a time_s or a sync column (or both)")
    for name in ("node_id", *FORCE_COLUMNS):
        if name not in names:
            raise ReferenceFileError(source, 1, f"missing column {name!r}")
    point = {"x_m", "y_m"} & names
    if "taxel" in names and point:
        raise ReferenceFileError(source, 1, "give either taxel or x_m and y_m, not both")
    if "taxel" not in names and point != {"x_m", "y_m"}:
        raise ReferenceFileError(source, 1, "needs a taxel column, or x_m and y_m")
    n = len(lines)
    node = _column(source, columns, lines, "node_id", int)
    _in_range(source, lines, "node_id", node, fields.NODE_IDS[0], fields.NODE_IDS[-1],
              fields.NODE_ID)
    time_s = _column(source, columns, lines, "time_s", float) if has_time else np.full(n, np.nan)
    sync = _column(source, columns, lines, "sync", int) if has_sync else np.zeros(n, np.int64)
    if has_sync:
        _in_range(source, lines, "sync", sync, 0, SYNC_MAX, f"a SYNC counter in 0..{SYNC_MAX}")
        if np.any(sync == 0) and np.any(sync != 0):
            k = int(np.flatnonzero(sync == 0)[0])
            raise ReferenceFileError(source, int(lines[k]), "sync: 0 (no counter) among rows "
                                     "that name one")
        has_sync = bool(np.any(sync != 0))
        if not (has_sync or has_time):
            raise ReferenceFileError(source, 1, "sync is 0 (no counter) in every row and there "
                                     "is no time_s column: nothing tells when a sample was")
    force = np.stack([_column(source, columns, lines, c, float) for c in FORCE_COLUMNS], axis=1)
    if "taxel" in names:
        taxel = _column(source, columns, lines, "taxel", int)
        _in_range(source, lines, "taxel", taxel, 0, TAXELS_PER_PATCH - 1, "a taxel in 0..8")
        form = "taxel"
    else:
        half = 1.5 * pitch_m * (1 + 1e-9)
        xy = [_column(source, columns, lines, c, float) for c in ("x_m", "y_m")]
        for name, values in zip(("x_m", "y_m"), xy, strict=True):
            _in_range(source, lines, name, values, -half, half,
                      f"on the patch (|{name}| <= {1.5 * pitch_m:g} m, 1.5 taxel pitches)")
        form = "point"
    # One sample per (node, time, sync), rows in file order within it; without a time, a
    # sample is a run of rows of one node with one counter (the counter wraps).
    if has_time:
        order = np.lexsort((lines, sync, time_s, node))
        key = np.stack([node[order].astype(np.float64), time_s[order], sync[order]], axis=1)
    else:
        order = np.lexsort((lines, node))
        key = np.stack([node[order], sync[order]], axis=1)
    new = np.ones(n, dtype=bool)
    if n:
        new[1:] = np.any(key[1:] != key[:-1], axis=1)
    sample_of = np.cumsum(new) - 1  # in ``order``
    count = int(new.sum())
    first = order[new]
    out = np.zeros((count, TAXELS_PER_PATCH, 3))
    if form == "taxel":
        seen = np.zeros((count, TAXELS_PER_PATCH), dtype=np.int64)
        np.add.at(seen, (sample_of, taxel[order]), 1)
        if np.any(seen > 1):
            s, t = (int(v) for v in np.argwhere(seen > 1)[0])
            rows_of = order[(sample_of == s) & (taxel[order] == t)]
            raise ReferenceFileError(source, int(lines[rows_of[1]]), f"taxel {t} of this "
                                     f"sample (node {int(node[rows_of[0]])}) given twice")
        out[sample_of, taxel[order]] = force[order]
        complete = np.all(seen == 1, axis=1)
    else:
        np.add.at(out, sample_of, spread_point(xy[0][order], xy[1][order], force[order],
                                               pitch_m))
        complete = np.ones(count, dtype=bool)
    incomplete: dict[int, int] = {}
    for n_id in node[first][~complete].tolist():
        incomplete[int(n_id)] = incomplete.get(int(n_id), 0) + 1
    keep = first[complete]
    return ReferenceSamples(
        source=source, node_id=node[keep], time_s=time_s[keep], sync=sync[keep],
        force_N=out[complete], row=lines[keep], has_time=has_time, has_sync=has_sync,
        form=form, rows=n, incomplete=incomplete)


class ReferenceWriter:
    """Writes reference samples in the taxel form as they come (a stream, not an atomic
    file): each sample's nine rows are written whole and flushed, so the file is valid up
    to its last complete sample at any moment; :meth:`close` syncs it to disk."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = os.fspath(path)
        # Written beside the target and renamed over it once it holds its header line; the
        # writer owns the stream until close(): it is written sample by sample.
        fd, tmp = create_beside(path)
        try:
            os.write(fd, (",".join(TAXEL_COLUMNS) + "\n").encode())
        except OSError as err:
            os.close(fd)
            discard(tmp)
            raise write_error(path, err) from err
        try:
            put_in_place(tmp, path)
        except BaseException:
            os.close(fd)
            raise
        self._handle: TextIO | None = os.fdopen(fd, "a", encoding="utf-8", newline="")
        self.samples = 0

    def write(self, time_s: float, sync: int, node_id: int, force_N: F64) -> None:
        """One sample: ``force_N`` (9, 3) of patch ``node_id`` at ``time_s``, answering
        SYNC counter ``sync`` (0: the SYNC carried none)."""
        handle = self._handle
        if handle is None:
            raise ValueError("the reference file is closed")
        time_s, sync, node_id = float(time_s), int(sync), int(node_id)
        lines = [f"{time_s!r},{sync},{node_id},{t},{fx!r},{fy!r},{fz!r}\n"
                 for t, (fx, fy, fz) in enumerate(np.asarray(force_N, np.float64).tolist())]
        try:
            handle.write("".join(lines))
            handle.flush()
        except OSError as err:
            raise write_error(self.path, err) from err
        self.samples += 1

    def close(self) -> None:
        handle, self._handle = self._handle, None
        if handle is not None:
            handle.flush()
            os.fsync(handle.fileno())
            handle.close()

    def __enter__(self) -> ReferenceWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
