"""The force sample on Zenoh, byte by byte, and the keys everything is published on.

A force sample is one :class:`~canbus.master.dataplane.ForceFrame` plus where it came
from (host, bus) and when the host handed it out and on to Zenoh. Its layout (schema
version 1, little-endian; ``docs/zenoh.md`` is the reference a reader in any language is
written from):

====== ========= ==================================================================
offset type      field
====== ========= ==================================================================
0      u8        schema version (1)
1      u8        flags: bit 0 complete, bit 1 published (force TPDOs on the bus)
2      u8        patch node-ID
3      u8        force node-ID
4      u8        SYNC counter byte (0: SYNC without counter)
5      u8        T, taxels (9)
6      u8        A, axes per taxel (3: Fx, Fy, Fz)
7      u8        0 (reserved)
8      u64       host cycle (1, 2, ...)
16     f64       SYNC time, s since the Unix epoch (the host's clock)
24     f64       published time: the data plane handed the sample out
32     f64       sent time: the sample was handed to Zenoh
40     f64[T*A]  forces in N, taxel-major (taxel 0 Fx, Fy, Fz, taxel 1 ...); 0 where invalid
40+8TA u8[T]     reason per taxel (``decoder.reasons``; 0 = valid)
..     u16       valid bits: bit k = taxel k valid
..     u8 + n    host name (length, UTF-8)
..     u8 + n    bus name (length, UTF-8)
..     ...       extensions to the end: (u8 tag, u16 length, bytes) each
====== ========= ==================================================================

A reader skips extensions whose tag it does not know: a later schema adds optional
fields as new tags without a new version; the version changes only when a field above
changes meaning or place. Events (state, EMCY, statistics) are msgpack maps with a ``v``.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any

import msgpack
import numpy as np

from canbus.master.dataplane import ForceFrame
from canbus.master.zenoh_settings import DEFAULT_PREFIX, key_chunk_problem
from skin.errors import SkinError
from skin.inputs import fields

SCHEMA_VERSION = 1
EVENT_VERSION = 1
FORCE_ENCODING = "application/octet-stream;canskin.forces.v1"
EVENT_ENCODING = "application/msgpack;canskin.event.v1"

COMPLETE, PUBLISHED = 0x01, 0x02
_HEAD = struct.Struct("<BBBBBBBxQddd")  # 40 bytes
HEAD_SIZE = _HEAD.size
_VALID = struct.Struct("<H")
_EXTENSION = struct.Struct("<BH")
MAX_TAXELS = 16  # the valid bits are a u16


class SchemaError(SkinError, ValueError):
    """A payload is not a force sample this reader can decode; says what is wrong."""


# -- keys ------------------------------------------------------------------------------------

def forces_key(prefix: str, host: str, bus: str, patch: int | str) -> str:
    """``{prefix}/{host}/{bus}/forces/{patch}``."""
    return f"{prefix}/{host}/{bus}/forces/{patch}"


def event_key(prefix: str, host: str, bus: str, kind: str, patch: int | str) -> str:
    """``{prefix}/{host}/{bus}/{kind}/{patch}``, kind ``state`` or ``emcy``."""
    return f"{prefix}/{host}/{bus}/{kind}/{patch}"


def stats_key(prefix: str, host: str) -> str:
    """``{prefix}/{host}/stats``: the host's statistics, once a period."""
    return f"{prefix}/{host}/stats"


def alive_key(prefix: str, host: str) -> str:
    """``{prefix}/{host}/alive``: the host's liveliness token, there while it publishes."""
    return f"{prefix}/{host}/alive"


def forces_selector(prefix: str = DEFAULT_PREFIX, *, host: str | None = None,
                    bus: str | None = None, patch: int | None = None) -> str:
    """The key expression of one patch, one bus, one host or the whole skin (None: any)."""
    for name, value in (("host", host), ("bus", bus)):
        if value is not None and (problem := key_chunk_problem(value)) is not None:
            raise SchemaError(f"{name}: {problem}")
    if patch is not None and not fields.is_node_id(patch):
        raise SchemaError(f"patch: must be {fields.NODE_ID}, got {patch}")
    return forces_key(prefix, host or "*", bus or "*", "*" if patch is None else patch)


# -- force samples ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Sample:
    """A decoded force sample: the API's frame and where and when it came from."""

    frame: ForceFrame
    host: str
    bus: str
    published: float  # time.time() when the host's data plane handed the sample out
    sent: float  # time.time() when the host handed it to Zenoh
    received: float = math.nan  # time.time() when this reader got it
    extensions: tuple[tuple[int, bytes], ...] = ()


def encode_forces(frame: ForceFrame, host: bytes, bus: bytes, published: float,
                  sent: float, extensions: tuple[tuple[int, bytes], ...] = ()) -> bytes:
    """One sample's payload (module docstring); ``host`` and ``bus`` already UTF-8."""
    force = frame.force_N
    if force.dtype != _F8 or not force.flags.c_contiguous:
        force = np.ascontiguousarray(force, dtype=_F8)
    taxels, axes = force.shape
    reason = frame.reason.astype(np.uint8, copy=False).tobytes()
    bits = 0
    for k, valid in enumerate(frame.valid.tolist()):
        bits |= bool(valid) << k
    flags = COMPLETE * bool(frame.complete) | PUBLISHED * bool(frame.published)
    parts = [
        _HEAD.pack(SCHEMA_VERSION, flags, frame.patch, frame.force_node, frame.sync_counter,
                   taxels, axes, frame.cycle, frame.timestamp, published, sent),
        force.tobytes(), reason, _VALID.pack(bits), bytes((len(host),)), host,
        bytes((len(bus),)), bus,
    ]
    for tag, data in extensions:
        parts.append(_EXTENSION.pack(tag, len(data)) + data)
    return b"".join(parts)


_F8 = np.dtype("<f8")


def decode_forces(payload: bytes | bytearray | memoryview, received: float = math.nan
                  ) -> Sample:
    """The :class:`Sample` a payload holds; :class:`SchemaError` says why not."""
    data = bytes(payload)
    if len(data) < HEAD_SIZE:
        raise SchemaError(f"{len(data)} bytes: shorter than the {HEAD_SIZE}-byte head")
    (version, flags, patch, force_node, counter, taxels, axes, cycle, t_sync, published,
     sent) = _HEAD.unpack_from(data)
    if version != SCHEMA_VERSION:
        raise SchemaError(f"schema version {version}; this reader knows {SCHEMA_VERSION}")
    if not 1 <= taxels <= MAX_TAXELS or not 1 <= axes <= 3:
        raise SchemaError(f"{taxels} taxels x {axes} axes: not a patch's shape")
    at = HEAD_SIZE + 8 * taxels * axes
    need = at + taxels + _VALID.size + 2
    if len(data) < need:
        raise SchemaError(f"{len(data)} bytes: {taxels} x {axes} forces need at least {need}")
    reasons = data[at:at + taxels]
    (bits,) = _VALID.unpack_from(data, at + taxels)
    expected = 0
    for k, code in enumerate(reasons):
        expected |= (code == 0) << k
    if bits != expected:
        raise SchemaError(f"valid bits 0x{bits:04X} and reasons disagree (a taxel is valid "
                          "iff its reason is 0)")
    force = np.frombuffer(data, _F8, taxels * axes, HEAD_SIZE).reshape(taxels, axes)
    if not np.isfinite(force).all():
        raise SchemaError("a force is not finite")
    at += taxels + _VALID.size
    host, at = _name(data, at, "host")
    bus, at = _name(data, at, "bus")
    extensions: list[tuple[int, bytes]] = []
    while at < len(data):
        if at + _EXTENSION.size > len(data):
            raise SchemaError(f"extension at byte {at}: truncated head")
        tag, length = _EXTENSION.unpack_from(data, at)
        at += _EXTENSION.size
        if at + length > len(data):
            raise SchemaError(f"extension {tag} at byte {at}: {length} bytes, "
                              f"{len(data) - at} left")
        extensions.append((tag, data[at:at + length]))
        at += length
    reason = np.frombuffer(reasons, np.uint8).copy()
    frame = ForceFrame(patch, force_node, cycle, counter, t_sync, force.astype(np.float64),
                       reason == 0, reason, bool(flags & COMPLETE), bool(flags & PUBLISHED))
    return Sample(frame, host, bus, published, sent, received, tuple(extensions))


def _name(data: bytes, at: int, what: str) -> tuple[str, int]:
    if at >= len(data):
        raise SchemaError(f"{what} name at byte {at}: missing")
    length = data[at]
    end = at + 1 + length
    if end > len(data):
        raise SchemaError(f"{what} name at byte {at}: {length} bytes, {len(data) - at - 1} left")
    try:
        return data[at + 1:end].decode("utf-8"), end
    except UnicodeDecodeError as err:
        raise SchemaError(f"{what} name at byte {at}: not UTF-8 ({err.reason})") from err


# -- events ----------------------------------------------------------------------------------


def encode_event(fields: dict[str, Any]) -> bytes:
    """An event (state, EMCY, statistics): a msgpack map with ``v`` first."""
    out: bytes = msgpack.packb({"v": EVENT_VERSION, **fields}, use_bin_type=True)
    return out


def decode_event(payload: bytes | bytearray | memoryview) -> dict[str, Any]:
    """An event's fields; :class:`SchemaError` if it is not a map of a known version."""
    try:
        event = msgpack.unpackb(bytes(payload), raw=False, strict_map_key=True)
    except Exception as err:  # msgpack raises several kinds on hostile bytes
        raise SchemaError(f"not a msgpack event: {err}") from err
    if not isinstance(event, dict):
        raise SchemaError(f"an event is a map, got {type(event).__name__}")
    if event.get("v") != EVENT_VERSION:
        raise SchemaError(f"event version {event.get('v')!r}; this reader knows "
                          f"{EVENT_VERSION}")
    return event

