"""Model files: msgpack maps with a schema, a version and typed arrays; never pickle.

Layout::

    {"schema": "canskin.decoder", "version": 4, "name": str,
     "params": {str: value}, "state": {str: value}, "meta": {str: value}}

where a value is None, bool, int, float, str, a map of values (depth-limited)
or an array ``{"dtype": "<f8", "shape": [...], "data": bytes}``. Reading
validates every field and refuses anything else with a ModelFileError that
names the field: a corrupt, truncated or hostile file never becomes a model.

``meta`` (version 2) is what training reports and decoding does not need: how
the hidden nodes were chosen, the validation curve, where training stopped.
Version 3 adds hybrid's residual threshold (``residual_threshold_``) and, for
lm-mlp in 3-axis mode, the per-taxel band of its training domain. Version 4
replaces lm-mlp's ellipsoid and bands by the checks of the whole patch
(``domain_.pattern`` and ``domain_.departure``, :mod:`decoder.patchcheck`). Files of
versions 1 (no ``meta``, no training domain), 2 and 3 are still read and decode as
they did; each decoder class says how an older state is upgraded
(``BaseDecoder._upgrade``).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any

import msgpack
import numpy as np

from skin.atomic import atomic_write
from skin.errors import ModelFileError
from skin.inputs.fields import short

SCHEMA = "canskin.decoder"
VERSION = 4
READABLE_VERSIONS = (1, 2, 3, 4)
MAX_FILE_BYTES = 64 * 1024 * 1024
MAX_ARRAY_ELEMENTS = 4_000_000
MAX_DIMS = 4
MAX_DEPTH = 4
ARRAY_KEYS = frozenset({"dtype", "shape", "data"})
DTYPES: dict[str, np.dtype[Any]] = {
    name: np.dtype(name) for name in ("<f8", "<i8", "|u1", "|b1")
}
TOP_KEYS = {1: frozenset({"schema", "version", "name", "params", "state"}),
            2: frozenset({"schema", "version", "name", "params", "state", "meta"}),
            3: frozenset({"schema", "version", "name", "params", "state", "meta"}),
            4: frozenset({"schema", "version", "name", "params", "state", "meta"})}


@dataclass(frozen=True)
class ModelContent:
    """What a model file holds once validated."""

    name: str
    params: dict[str, Any]
    state: dict[str, Any]
    version: int = VERSION
    meta: dict[str, Any] = field(default_factory=dict)


def encode_array(array: np.ndarray) -> dict[str, Any]:
    a = np.ascontiguousarray(array)
    dtype = a.dtype.newbyteorder("<") if a.dtype.byteorder == ">" else a.dtype
    if dtype.str not in DTYPES:
        raise TypeError(f"cannot store arrays of dtype {a.dtype}")
    a = a.astype(dtype, copy=False)
    return {"dtype": dtype.str, "shape": list(a.shape), "data": a.tobytes()}


def _encode(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return encode_array(value)
    if isinstance(value, dict):
        return {str(k): _encode(v) for k, v in value.items()}
    if isinstance(value, np.generic):
        return value.item()
    return value


def write_model(
    path: str | os.PathLike[str], name: str, params: dict[str, Any], state: dict[str, Any],
    meta: dict[str, Any] | None = None,
) -> None:
    """Write a model file atomically (complete or absent)."""
    doc = {"schema": SCHEMA, "version": VERSION, "name": name,
           "params": _encode(params), "state": _encode(state), "meta": _encode(meta or {})}
    payload = msgpack.packb(doc, use_bin_type=True)
    with atomic_write(path) as handle:
        handle.write(payload)


def decode_array(obj: dict[str, Any], field: str) -> np.ndarray:
    """Validate an encoded array and return a read-only-safe copy."""
    dtype_str, shape, data = obj["dtype"], obj["shape"], obj["data"]
    if not isinstance(dtype_str, str) or dtype_str not in DTYPES:
        raise ModelFileError(f"{field}.dtype: {dtype_str!r} is not one of {sorted(DTYPES)}")
    if not (isinstance(shape, list) and len(shape) <= MAX_DIMS
            and all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape)):
        raise ModelFileError(f"{field}.shape: must be a list of at most {MAX_DIMS} sizes >= 0")
    size = math.prod(shape)
    if size > MAX_ARRAY_ELEMENTS:
        raise ModelFileError(f"{field}.shape: {shape} holds {size} elements, "
                             f"more than the limit of {MAX_ARRAY_ELEMENTS}")
    if not isinstance(data, bytes):
        raise ModelFileError(f"{field}.data: must be bytes")
    dtype = DTYPES[dtype_str]
    if len(data) != size * dtype.itemsize:
        raise ModelFileError(f"{field}.data: {len(data)} bytes do not match shape {shape} "
                             f"of {dtype_str} ({size * dtype.itemsize} bytes)")
    array: np.ndarray = np.frombuffer(data, dtype=dtype).reshape(shape)
    array = array.astype(array.dtype.newbyteorder("="))
    if array.dtype.kind == "b" and not np.all(np.frombuffer(data, dtype=np.uint8) <= 1):
        raise ModelFileError(f"{field}.data: booleans must be 0 or 1")
    if array.dtype.kind == "f" and not np.all(np.isfinite(array)):
        raise ModelFileError(f"{field}.data: contains NaN or infinity")
    return array


def _decode(value: Any, field: str, depth: int) -> Any:
    if value is None or isinstance(value, bool | int | str):
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ModelFileError(f"{field}: must be finite, got {value!r}")
        return value
    if isinstance(value, dict):
        if set(value) == ARRAY_KEYS:
            return decode_array(value, field)
        if depth >= MAX_DEPTH:
            raise ModelFileError(f"{field}: nested deeper than {MAX_DEPTH} levels")
        for key in value:
            if not isinstance(key, str):
                raise ModelFileError(f"{field}: key {short(key)} is not a string")
        return {k: _decode(v, f"{field}.{k}", depth + 1) for k, v in value.items()}
    raise ModelFileError(f"{field}: unsupported value of type {type(value).__name__}")


def _no_ext(code: int, data: bytes) -> Any:
    raise ValueError(f"extension type {code} is not allowed")


def unpack_model(payload: bytes) -> ModelContent:
    """Validate raw msgpack bytes as a model document."""
    if len(payload) > MAX_FILE_BYTES:
        raise ModelFileError(f"file: larger than the limit of {MAX_FILE_BYTES} bytes")
    try:
        doc = msgpack.unpackb(
            payload, raw=False, strict_map_key=True, use_list=True, ext_hook=_no_ext,
            max_bin_len=MAX_ARRAY_ELEMENTS * 8,
            max_str_len=1 << 16, max_array_len=64, max_map_len=256, max_ext_len=0,
        )
    except (ValueError, msgpack.UnpackException) as err:
        raise ModelFileError(f"file: not a valid msgpack document ({err})") from err
    if not isinstance(doc, dict):
        raise ModelFileError("file: top level must be a map")
    for key in doc:
        if not isinstance(key, str):
            raise ModelFileError(f"file: key {short(key)} is not a string")
    if doc.get("schema") != SCHEMA:
        raise ModelFileError(f"schema: expected {SCHEMA!r}, got {short(doc.get('schema'))}")
    version = doc.get("version")
    if isinstance(version, bool) or version not in READABLE_VERSIONS:
        *older, newest = (str(v) for v in READABLE_VERSIONS)
        raise ModelFileError(f"version: this canskin reads versions {', '.join(older)} and "
                             f"{newest}, got {short(version)}")
    keys = TOP_KEYS[version]
    missing = sorted(keys - set(doc))
    extra = sorted(set(doc) - keys)
    if missing or extra:
        what = f"missing {missing[0]!r}" if missing else f"unknown key {extra[0]!r}"
        raise ModelFileError(f"file: {what}")
    if not isinstance(doc["name"], str) or not doc["name"]:
        raise ModelFileError("name: must be a non-empty string")
    for key in ("params", "state", "meta"):
        if key in doc and not isinstance(doc[key], dict):
            raise ModelFileError(f"{key}: must be a map")
    return ModelContent(name=doc["name"], params=_decode(doc["params"], "params", 1),
                        state=_decode(doc["state"], "state", 1), version=version,
                        meta=_decode(doc.get("meta", {}), "meta", 1))


def read_model(path: str | os.PathLike[str]) -> ModelContent:
    """Read and validate a model file; ModelFileError names the file and the first bad
    field."""
    try:
        with open(path, "rb") as handle:
            payload = handle.read(MAX_FILE_BYTES + 1)
    except FileNotFoundError as err:
        raise ModelFileError(f"{os.fspath(path)}: no such file") from err
    except IsADirectoryError as err:
        raise ModelFileError(f"{os.fspath(path)}: is a folder, not a model file") from err
    except OSError as err:
        raise ModelFileError(f"{os.fspath(path)}: cannot read: {err.strerror}") from err
    try:
        return unpack_model(payload)
    except ModelFileError as err:
        raise ModelFileError(f"{os.fspath(path)}: {err}") from err
