"""A force sample as the recorders see it (:class:`Sample`: the fields of the host's
``ForceFrame`` they use), the contact figures an MCAP recording keeps
(:class:`ContactFields`), and a sample as 320 fixed bytes, for the recording process of
``skin run --record`` (``skin.commands.common.recordproc``).

Layout, little-endian: time_s f64, cycle u32, patch, force_node, sync_counter u8, flags u8
(bit 0 complete, 1 published, 2 has a contact summary); force_N 27 f64 (taxel-major);
valid 9 u8; reason 9 u8; the summary: force_N 3 f64, torque_Nm 3 f64, cop_m 2 f64,
cop_defined u8, state byte u8, contact taxels u16 (bit k = taxel k), slipping taxels u16
(zeros without a summary). Exact: every double is copied, never converted.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

_HEAD = struct.Struct("<dIBBBB")
_CONTACT = struct.Struct("<8dBBHH")
SIZE = _HEAD.size + 27 * 8 + 18 + _CONTACT.size
COMPLETE, PUBLISHED, HAS_CONTACT = 1, 2, 4
_BITS = 1 << np.arange(9)


class Sample(Protocol):
    """One patch's forces for one SYNC cycle (the host's ``ForceFrame`` is one)."""

    @property
    def patch(self) -> int: ...
    @property
    def force_node(self) -> int: ...
    @property
    def cycle(self) -> int: ...
    @property
    def sync_counter(self) -> int: ...
    @property
    def timestamp(self) -> float: ...
    @property
    def force_N(self) -> NDArray[np.float64]: ...
    @property
    def valid(self) -> NDArray[np.bool_]: ...
    @property
    def reason(self) -> NDArray[np.uint8]: ...
    @property
    def complete(self) -> bool: ...
    @property
    def published(self) -> bool: ...
    @property
    def contact(self) -> Any: ...


@dataclass(frozen=True)
class WireSample:
    """A :class:`Sample` read back from its bytes (``contact`` is None: its figures come
    apart, as :class:`ContactFields`)."""

    patch: int
    force_node: int
    cycle: int
    sync_counter: int
    timestamp: float
    force_N: NDArray[np.float64]
    valid: NDArray[np.bool_]
    reason: NDArray[np.uint8]
    complete: bool
    published: bool
    contact: None = None


@dataclass(frozen=True)
class ContactFields:
    """What an MCAP recording keeps of a sample's contact summary (docs/mcap.md)."""

    force_N: NDArray[np.float64]  # (3,)
    torque_Nm: NDArray[np.float64]  # (3,)
    cop_m: NDArray[np.float64]  # (2,)
    cop_defined: bool
    state_byte: int
    contact_taxels: NDArray[np.bool_]  # (9,)
    taxel_slip: NDArray[np.bool_]  # (9,)


def contact_fields(contact: Any) -> ContactFields | None:
    """The fields of a :class:`~skin.contact_state.ContactSummary` (or None, or fields)."""
    if contact is None or isinstance(contact, ContactFields):
        return contact
    return ContactFields(np.asarray(contact.force_N, np.float64),
                         np.asarray(contact.torque_Nm, np.float64),
                         np.asarray(contact.cop_m, np.float64), bool(contact.cop_defined),
                         int(contact.batch.state_byte[contact.row]),
                         np.asarray(contact.contact_taxels, bool),
                         np.asarray(contact.taxel_slip, bool))


def pack(frame: Sample) -> bytes:
    contact = contact_fields(frame.contact)
    flags = COMPLETE * frame.complete + PUBLISHED * frame.published + \
        HAS_CONTACT * (contact is not None)
    head = _HEAD.pack(frame.timestamp, frame.cycle, frame.patch, frame.force_node,
                      frame.sync_counter, flags)
    body = np.ascontiguousarray(frame.force_N, "<f8").tobytes() + \
        np.asarray(frame.valid, np.uint8).tobytes() + np.asarray(frame.reason, np.uint8).tobytes()
    if contact is None:
        return head + body + bytes(_CONTACT.size)
    tail = _CONTACT.pack(*contact.force_N.tolist(), *contact.torque_Nm.tolist(),
                         *contact.cop_m.tolist(), contact.cop_defined, contact.state_byte,
                         int(_BITS @ contact.contact_taxels), int(_BITS @ contact.taxel_slip))
    return head + body + tail


def unpack(data: bytes) -> tuple[WireSample, ContactFields | None]:
    """The sample (``contact`` None) and its contact fields; ValueError if not ``SIZE``."""
    if len(data) != SIZE:
        raise ValueError(f"a sample is {SIZE} bytes, got {len(data)}")
    t, cycle, patch, node, counter, flags = _HEAD.unpack_from(data)
    at = _HEAD.size
    force = np.frombuffer(data, "<f8", 27, at).reshape(9, 3).astype(np.float64)
    at += 27 * 8
    valid = np.frombuffer(data, np.uint8, 9, at).astype(bool)
    reason = np.frombuffer(data, np.uint8, 9, at + 9).copy()
    frame = WireSample(patch=patch, force_node=node, cycle=cycle, sync_counter=counter,
                       timestamp=t, force_N=force, valid=valid, reason=reason,
                       complete=bool(flags & COMPLETE), published=bool(flags & PUBLISHED))
    if not flags & HAS_CONTACT:
        return frame, None
    *values, defined, state, touch, slip = _CONTACT.unpack_from(data, at + 18)
    return frame, ContactFields(np.array(values[:3]), np.array(values[3:6]),
                                np.array(values[6:8]), bool(defined), state,
                                (touch & _BITS) != 0, (slip & _BITS) != 0)
