"""The dataset file: one .npz of resistances, true forces and JSON meta (format: docs/sim.md).

Written by hand with zipfile so identical content gives identical bytes (fixed
timestamps, fixed member order), atomically, and never with pickle. Read through
:func:`skin.inputs.npz.read_npz` (declared sizes checked before anything is allocated)
and checked value by value: resistances in 0..1e12 ohm, +inf (open) or NaN, forces
finite and within :data:`FORCE_LIMIT_N`, a JSON meta object whose constants are valid.
:func:`read_training_set` also refuses data nothing can be learned from.
"""

from __future__ import annotations

import json
import math
import os
import zipfile
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skin.atomic import atomic_write
from skin.errors import ConfigError, DatasetError
from skin.inputs import fields
from skin.inputs.npz import read_npz

F64 = NDArray[np.float64]
KEYS = ("resistance_ohm", "force_N", "meta")
META_KEYS = ("scene", "seed", "effects", "constants", "mode")
_EPOCH = (1980, 1, 1, 0, 0, 0)
FORCE_LIMIT_N = 1e4
"""No force in a dataset is larger (10 kN on a 15 mm taxel is a unit mistake)."""
RESISTANCE_LIMIT_OHM = 1e12
"""No finite resistance is larger (+inf stands for an open circuit)."""
MAX_META_CHARS = 1 << 20
MIN_TRAINING_SAMPLES = 10


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
    """Read and validate a dataset; DatasetError names the file and what is wrong."""
    where = os.fspath(path)
    arrays = read_npz(path, lambda problem: DatasetError(f"{where}: {problem}"))
    missing = [k for k in KEYS if k not in arrays]
    if missing:
        raise DatasetError(f"{where}: missing {', '.join(missing)}")
    r, f, meta_array = (arrays[k] for k in KEYS)
    meta = _meta(meta_array, where)
    _check(r, f, meta, where)
    _check_values(r, f, where)
    return Dataset(resistance_ohm=r, force_N=f, meta=meta)


def _meta(meta_array: np.ndarray, where: str) -> dict[str, Any]:
    if meta_array.shape != () or meta_array.dtype.kind != "U":
        raise DatasetError(f"{where}: meta must be a 0-d unicode array")
    text = str(meta_array)
    if len(text) > MAX_META_CHARS:
        raise DatasetError(f"{where}: meta is longer than {MAX_META_CHARS} characters")
    try:
        meta = json.loads(text, parse_constant=_no_constant)
    except (json.JSONDecodeError, ValueError) as err:
        raise DatasetError(f"{where}: meta is not valid JSON ({err})") from err
    except RecursionError:
        raise DatasetError(f"{where}: meta is nested too deeply") from None
    if not isinstance(meta, dict):
        raise DatasetError(f"{where}: meta must be a JSON object")
    _meta_nodes(meta, where)
    if isinstance(meta.get("constants"), dict):
        from skin.constants import SensorConstants

        try:
            SensorConstants.from_dict(meta["constants"], where="meta.constants")
        except ConfigError as err:
            raise DatasetError(f"{where}: {err}") from err
    elif "constants" in meta:
        raise DatasetError(f"{where}: meta.constants must be a JSON object")
    return meta


def _meta_nodes(meta: dict[str, Any], where: str) -> None:
    """``node_ids`` (a recording's dataset) and ``scene.patches`` (a scene's): node-IDs."""
    nodes = meta.get("node_ids")
    scene = meta.get("scene")
    if isinstance(scene, dict):  # a scene's dataset (else its name, or a recording's)
        patches = scene.get("patches")
        if patches is not None:
            if not (isinstance(patches, list) and all(isinstance(p, dict) for p in patches)):
                raise DatasetError(f"{where}: meta.scene.patches must be a list of objects")
            nodes = [p.get("node_id") for p in patches] if nodes is None else nodes
    if nodes is None:
        return
    if not isinstance(nodes, list) or not all(
            fields.is_node_id(n) for n in nodes):
        raise DatasetError(f"{where}: meta's node-IDs must be integers in 1..127, got "
                           f"{str(nodes)[:60]}")


def _no_constant(name: str) -> float:
    raise ValueError(f"{name} is not a finite number")


def _check_values(r: np.ndarray, f: np.ndarray, where: str) -> None:
    """Every resistance in 0..RESISTANCE_LIMIT_OHM, +inf (open) or NaN (a taxel that gave
    no reading: decoders mask both), every force finite and within FORCE_LIMIT_N; the
    first bad value is named by its index."""
    bad_r = ~(((r >= 0) & (r <= RESISTANCE_LIMIT_OHM)) | (r == math.inf) | np.isnan(r))
    if bad_r.any():
        at = tuple(int(i) for i in np.argwhere(bad_r)[0])
        raise DatasetError(f"{where}: resistance_ohm{list(at)} is {float(r[at])!r}: must be in "
                           f"0..{RESISTANCE_LIMIT_OHM:g} ohm, inf (open) or nan (no reading)")
    bad_f = ~(np.abs(f) <= FORCE_LIMIT_N)
    if bad_f.any():
        at = tuple(int(i) for i in np.argwhere(bad_f)[0])
        raise DatasetError(f"{where}: force_N{list(at)} is {float(f[at])!r}: must be finite and "
                           f"within ±{FORCE_LIMIT_N:g} N")


def read_training_set(path: str | os.PathLike[str]) -> Dataset:
    """:func:`read_dataset`, refusing data nothing can be learned from: fewer than
    :data:`MIN_TRAINING_SAMPLES` samples, or samples that all carry the same forces or
    the same resistances."""
    ds = read_dataset(path)
    where = os.fspath(path)
    n = ds.resistance_ohm.shape[0]
    if n < MIN_TRAINING_SAMPLES:
        raise DatasetError(f"{where}: {n} samples; training needs {MIN_TRAINING_SAMPLES} "
                           "or more")
    for name, values in (("force_N", ds.force_N), ("resistance_ohm", ds.resistance_ohm)):
        if np.all(values == values[:1]):
            raise DatasetError(f"{where}: all {n} samples have the same {name}: there is "
                               "nothing to learn from")
    return ds
