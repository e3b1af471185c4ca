"""The dataset file: one .npz of resistances, true forces and JSON meta (format: docs/sim.md).

Written by hand with zipfile so identical content gives identical bytes (fixed
timestamps, fixed member order), atomically, and never with pickle.
"""

from __future__ import annotations

import json
import os
import zipfile
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skin.atomic import atomic_write
from skin.errors import DatasetError

F64 = NDArray[np.float64]
KEYS = ("resistance_ohm", "force_N", "meta")
META_KEYS = ("scene", "seed", "effects", "constants", "mode")
_EPOCH = (1980, 1, 1, 0, 0, 0)


@dataclass(frozen=True)
class Dataset:
    """resistance_ohm (samples, patches, 9, P), force_N (samples, patches, 9, 3), meta."""

    resistance_ohm: F64
    force_N: F64
    meta: dict[str, Any]

    def __post_init__(self) -> None:
        _check(self.resistance_ohm, self.force_N, self.meta, "dataset")


def _check(r: np.ndarray, f: np.ndarray, meta: Any, where: str) -> None:
    for name, a in (("resistance_ohm", r), ("force_N", f)):
        if a.dtype != np.float64:
            raise DatasetError(f"{where}: {name} must be float64, got {a.dtype}")
    if r.ndim != 4 or r.shape[2] != 9 or r.shape[3] not in (1, 3):
        expected = "(samples, patches, 9, 1|3)"
        raise DatasetError(f"{where}: resistance_ohm must be {expected}, got {r.shape}")
    if f.shape != (*r.shape[:3], 3):
        raise DatasetError(f"{where}: force_N must be {(*r.shape[:3], 3)}, got {f.shape}")
    if not isinstance(meta, dict):
        raise DatasetError(f"{where}: meta must be a JSON object")
    missing = [k for k in META_KEYS if k not in meta]
    if missing:
        raise DatasetError(f"{where}: meta lacks {', '.join(missing)}")
    if meta["mode"] != ("z" if r.shape[3] == 1 else "xyz"):
        raise DatasetError(f"{where}: meta mode {meta['mode']!r} does not match P = {r.shape[3]}")


def write_dataset(path: str | os.PathLike[str], ds: Dataset) -> None:
    """Write ``ds`` to ``path`` (.npz); identical content gives identical bytes."""
    meta = np.array(json.dumps(ds.meta, sort_keys=True, allow_nan=False))
    arrays = (("resistance_ohm", ds.resistance_ohm), ("force_N", ds.force_N), ("meta", meta))
    with atomic_write(path) as handle, zipfile.ZipFile(handle, "w", zipfile.ZIP_STORED) as zf:
        for name, array in arrays:
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_EPOCH)
            info.external_attr = 0o644 << 16
            with zf.open(info, "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asarray(array, order="C"), allow_pickle=False)


def read_dataset(path: str | os.PathLike[str]) -> Dataset:
    """Read and validate a dataset; DatasetError names what is wrong."""
    where = os.fspath(path)
    try:
        with np.load(path, allow_pickle=False) as npz:
            missing = [k for k in KEYS if k not in npz.files]
            if missing:
                raise DatasetError(f"{where}: missing {', '.join(missing)}")
            r, f, meta_array = (npz[k] for k in KEYS)
    except (ValueError, zipfile.BadZipFile, EOFError) as err:
        if isinstance(err, DatasetError):
            raise
        raise DatasetError(f"{where}: not a readable dataset .npz ({err})") from err
    if meta_array.shape != () or meta_array.dtype.kind != "U":
        raise DatasetError(f"{where}: meta must be a 0-d unicode array")
    try:
        meta = json.loads(str(meta_array))
    except json.JSONDecodeError as err:
        raise DatasetError(f"{where}: meta is not valid JSON ({err})") from err
    _check(r, f, meta, where)
    return Dataset(resistance_ohm=r, force_N=f, meta=meta)
