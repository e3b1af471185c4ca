"""A batch of force nodes' TPDO frames (:class:`FrameBatcher`): every object value of every
node in one int64 table, a row per node, and each mapping's PDOs cut from the table's
little-endian bytes by one gather (an integer object of k bytes is the low k bytes of its
int64, as ``PdoCodec.pack`` would write it).

The object values: 0x2000 the forces in mN, 0x2004 the status, 0x2005 the valid bits,
0x1001, 0x2006 the SYNC counter answered and 0x2008 the contact summary
(:mod:`canbus.contact_record`). The host's contact batches bring the default contact PDO's
figures already computed (:meth:`~canbus.master.contact.PublishedBatch.take_published`):
they are counted with the forces, by the same calls.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canbus import contact_record
from canbus.pdo_codec import MappedEntry, PdoCodec
from skin.constants import TAXELS_PER_PATCH
from skin.contact_state import ContactBatch
from skin.errors import ConfigError

FORCES, STATUS, VALID, ANSWERED = 0x2000, 0x2004, 0x2005, 0x2006
CONTACT = contact_record.CONTACT
NO_VALUE = -0x8000
"""INTEGER16 0x8000: the component has no value (invalid taxel or beyond +-32.767 N)."""
COMPLETE = 1 << 15
"""Bit 15 of 0x2005: every PDO of the patch arrived exactly once in the SYNC cycle."""
MAX_MN = 0x7FFF
UNSPECIFIED = 0xFF
"""0x2004 of an invalid taxel when the caller gives no reason code."""
Frame = tuple[int, bytes]


def forces_to_mN(force_N: ArrayLike, valid: ArrayLike) -> tuple[NDArray[np.int16],
                                                                 NDArray[np.bool_]]:
    """``(..., 9, 3)`` N and ``(..., 9)`` valid -> INTEGER16 mN and the taxels valid on the bus.

    A taxel is valid on the bus when it is ``valid`` and each of its components is finite
    and rounds within +-32767 mN; all three components of any other taxel are ``NO_VALUE``.
    """
    f = np.asarray(force_N, dtype=np.float64)
    ok = np.asarray(valid, dtype=bool)
    mN = np.rint(f * 1000.0)
    fits = np.abs(mN) <= MAX_MN  # False for NaN and inf too
    bus_valid = fits.all(axis=-1) & ok
    out = np.where(bus_valid[..., None], mN, NO_VALUE).astype(np.int16)
    return out, bus_valid


def valid_bits(valid: ArrayLike, complete: ArrayLike) -> NDArray[np.uint16]:
    """Object 0x2005: ``(..., 9)`` valid and ``(...)`` complete -> UNSIGNED16."""
    v = np.asarray(valid, dtype=np.uint16)
    bits = (v << np.arange(v.shape[-1], dtype=np.uint16)).sum(axis=-1, dtype=np.uint16)
    complete_bit = np.where(np.asarray(complete, dtype=bool), COMPLETE, 0).astype(np.uint16)
    return np.asarray(bits | complete_bit, dtype=np.uint16)


class FrameBatcher:
    """Packs batches of force nodes' TPDO frames (:meth:`frames`), keeping what each
    mapping needs: its layout (one per distinct mapping, found once per codec) and the
    read-only blocks of zeros and "no summary" a batch of its size takes."""

    def __init__(self) -> None:
        self._layouts: weakref.WeakKeyDictionary[PdoCodec, _Layout] = \
            weakref.WeakKeyDictionary()
        self._shapes: dict[tuple[tuple[MappedEntry, ...], ...], _Layout] = {}
        self._zeros: dict[tuple[int, int], NDArray[np.int64]] = {}
        self._no_summaries: dict[tuple[int, tuple[int, ...]], NDArray[np.int64]] = {}
        self._counts_per_unit = np.array([1000.0] * 27 + [
            contact_record.COUNTS_PER_UNIT[sub] for sub in contact_record.PUBLISHED])

    def frames(self, nodes: Sequence[Publishing], force_N: NDArray[np.float64],
               valid: NDArray[np.bool_], complete: NDArray[np.bool_],
               reason: NDArray[np.uint8] | None = None,
               answered: ArrayLike = 0, contact: ContactBatch | None = None,
               ) -> list[list[Frame]]:
        """``ForceNode.frames`` of ``n`` nodes at once: ``(n, 9, 3)``, ``(n, 9)``, ``(n,)``;
        ``answered``: the counter byte of the SYNC each sample answers (0x2006), ``(n,)`` or
        one for all; ``contact``: the samples' contact summaries (0x2008; None: no summary).

        Every object value goes into one int64 table (a row per node); the TPDOs of nodes
        mapped alike are cut from its little-endian bytes by one gather (an integer object
        of k bytes is the low k bytes of its int64, as ``PdoCodec.pack`` would write it).
        """
        n = len(nodes)
        take = getattr(contact, "take_published", None)
        published = None if take is None else take()
        if published is None:
            mN, bus_valid = forces_to_mN(force_N, valid)
            flat_mN, head = mN.reshape(n, 27), None
        else:
            counts, bus_valid = self._counts(force_N, valid, *published)
            flat_mN, head = counts[:, :27], counts[:, 27:]
        bits = valid_bits(bus_valid, complete)
        status = (np.where(bus_valid, 0, UNSPECIFIED).astype(np.uint8) if reason is None
                  else np.asarray(reason, dtype=np.uint8))
        bits_list = bits.tolist()
        counters = np.broadcast_to(np.asarray(answered, dtype=np.int64), (n,))
        groups: dict[_Layout, list[tuple[int, PdoCodec]]] = {}
        counter_list = counters.tolist()
        for i, node in enumerate(nodes):
            codec = node.adopt(flat_mN[i], status[i], bits_list[i], counter_list[i], contact, i)
            groups.setdefault(self._layout(codec), []).append((i, codec))
        subs = sorted({s for key in groups for s in key.contact_subs})
        table = np.concatenate([flat_mN, status, bits[:, None], self._zero_block(n, 1),
                                counters[:, None],
                                *self._contact_columns(contact, subs, n, head)],
                               axis=1, dtype=_TABLE, casting="unsafe").view(np.uint8)
        out: list[list[Frame]] = [[] for _ in range(n)]
        for key, members in groups.items():
            rows = table if len(members) == n else table[[i for i, _ in members]]
            payload = rows[:, key.gather].tobytes()
            width = key.width
            for m, (i, codec) in enumerate(members):
                at = m * width
                out[i] = [(cob, payload[at + start:at + end]) for cob, (start, end)
                          in zip(codec.cob_ids.tolist(), key.spans, strict=True)]
        return out

    def _counts(self, force_N: NDArray[np.float64], valid: NDArray[np.bool_],
                published: NDArray[np.float64], has: NDArray[np.bool_]
                ) -> tuple[NDArray[np.int16], NDArray[np.bool_]]:
        """:func:`forces_to_mN` of ``(n, 9, 3)`` forces with the host's contact figures
        (``(3, n)`` in SI units, ``has``: where they have a value) as three more columns,
        counted as :func:`canbus.contact_record.encode` counts them: ``(n, 30)`` INTEGER16,
        the same rounding and the same check for all, and the taxels valid on the bus."""
        n = len(force_N)
        x = np.concatenate((force_N.reshape(n, 27), published.T), axis=1)
        x *= self._counts_per_unit
        np.rint(x, out=x)
        fits = np.abs(x) <= MAX_MN  # False for NaN and inf too
        bus_valid = fits[:, :27].reshape(n, TAXELS_PER_PATCH, 3).all(axis=-1) & valid
        fits[:, :27] = np.repeat(bus_valid, 3, axis=1)  # an invalid taxel has no component
        fits[:, 27:] &= has.T
        counts: NDArray[np.int16] = np.where(fits, x, NO_VALUE).astype(np.int16)
        return counts, bus_valid

    def _contact_columns(self, contact: ContactBatch | None, subs: list[int], n: int,
                         head: NDArray[np.int16] | None) -> list[NDArray[Any]]:
        """The table's 0x2008 columns (:data:`CONTACT_ORDER`), the mapped ones (``subs``)
        filled in; none when nothing maps them. ``head``: the published sub-indices' values
        already counted (:meth:`_counts`); a node without a contact judge holds no
        summary."""
        if not subs:
            return []
        if head is not None and contact is not None and set(subs) <= _HEAD_SUBS:
            return [head, contact.state_byte[:, None], contact.instant.taxel_count[:, None],
                    self._zero_block(n, len(CONTACT_ORDER) - len(_HEAD_SUBS))]
        if contact is None:
            return [self._no_summary(n, tuple(subs))]
        out = np.zeros((n, contact_record.SUBS), dtype=np.int64)
        places = np.array([_CONTACT_COLUMN[s] for s in subs], dtype=np.intp)
        out[:, places] = contact_record.encode(contact, subs)
        absent = getattr(contact, "absent", None)
        if absent is not None:
            none = np.flatnonzero(absent)
            out[np.ix_(none, places)] = contact_record.no_summary(subs, len(none))
        return [out]

    def _zero_block(self, n: int, k: int) -> NDArray[np.int64]:
        """A read-only ``(n, k)`` block of zeros, made once."""
        block = self._zeros.get((n, k))
        if block is None:
            if len(self._zeros) > _BLOCKS_KEPT:
                self._zeros.clear()
            block = self._zeros[n, k] = np.zeros((n, k), dtype=np.int64)
            block.flags.writeable = False
        return block

    def _no_summary(self, n: int, subs: tuple[int, ...]) -> NDArray[np.int64]:
        """A read-only ``(n, 15)`` contact block of nodes without a summary, made once."""
        block = self._no_summaries.get((n, subs))
        if block is None:
            if len(self._no_summaries) > _BLOCKS_KEPT:
                self._no_summaries.clear()
            block = np.zeros((n, contact_record.SUBS), dtype=np.int64)
            block[:, [_CONTACT_COLUMN[s] for s in subs]] = contact_record.no_summary(subs, n)
            block.flags.writeable = False
            self._no_summaries[n, subs] = block
        return block

    def _layout(self, codec: PdoCodec) -> _Layout:
        """The codec's shape, one object per distinct mapping (found once per codec)."""
        layout = self._layouts.get(codec)
        if layout is None:
            entries = tuple(lay.entries for lay in codec.layouts)
            layout = self._shapes.get(entries)
            if layout is None:
                layout = self._shapes[entries] = _shape(codec, entries)
            self._layouts[codec] = layout
        return layout


def batch_frames(nodes: Sequence[Publishing], force_N: NDArray[np.float64],
                 valid: NDArray[np.bool_], complete: NDArray[np.bool_],
                 reason: NDArray[np.uint8] | None = None,
                 answered: ArrayLike = 0, contact: ContactBatch | None = None,
                 ) -> list[list[Frame]]:
    """:meth:`FrameBatcher.frames` of one batch, nothing kept."""
    return FrameBatcher().frames(nodes, force_N, valid, complete, reason, answered, contact)


CONTACT_ORDER = (*contact_record.PUBLISHED, contact_record.STATE, contact_record.COUNT,
                 *(s for s in range(1, contact_record.SUBS + 1)
                   if s not in (*contact_record.PUBLISHED, contact_record.STATE,
                                contact_record.COUNT)))
"""The 0x2008 sub-indices in the order of the table's contact columns: first those of the
default contact PDO, as the host computes them."""
_CONTACT_COLUMN = MappingProxyType({sub: k for k, sub in enumerate(CONTACT_ORDER)})
_HEAD_SUBS = frozenset(CONTACT_ORDER[:len(contact_record.PUBLISHED) + 2])
_BLOCKS_KEPT = 256
"""How many blocks of each kind a :class:`FrameBatcher` keeps (then it starts anew)."""


@dataclass(frozen=True, eq=False)
class _Layout:
    """A mapping shape: nodes with the same one (identity) are packed together."""

    gather: NDArray[np.intp]  # every PDO's bytes, one after the other, from a table row's
    # bytes (int64 columns ``[forces (27), status (9), 0x2005, 0x1001, 0x2006, 0x2008 (15,
    # in CONTACT_ORDER)]``)
    width: int  # the bytes of all of a node's PDOs
    spans: tuple[tuple[int, int], ...]  # each PDO's bytes among them
    contact_subs: tuple[int, ...]  # the 0x2008 sub-indices it maps


_FIRST_COLUMN = MappingProxyType(
    {FORCES: 0, STATUS: 27, VALID: 36, 0x1001: 37, ANSWERED: 38, CONTACT: 39})
"""Each published object's first column in the table."""
_TABLE = np.dtype("<i8")


def _shape(codec: PdoCodec, entries: tuple[tuple[MappedEntry, ...], ...]) -> _Layout:
    """The layout of a mapping (``entries``: each PDO's, of ``codec``)."""
    gather: list[int] = []
    spans = []
    for pdo in entries:
        start = len(gather)
        for entry in pdo:
            gather.extend(_bytes_of(entry))
        spans.append((start, len(gather)))
    contact_subs = tuple(sorted({sub for obj, sub in codec.variables if obj == CONTACT}))
    return _Layout(np.array(gather, dtype=np.intp), len(gather), tuple(spans), contact_subs)


def _bytes_of(entry: MappedEntry) -> range:
    """Where a mapped object's bytes are in a table row's bytes (its int64's low bytes)."""
    obj, sub = entry.index, entry.subindex
    if obj not in _FIRST_COLUMN:  # TpdoTable admits only the EDS's mappable objects
        raise ConfigError("pdo mapping", f"0x{obj:04X}:{sub:02X} is not published")
    if entry.bits % 8 or not 0 < entry.bits <= 64:  # every one of them is an integer
        raise ConfigError("pdo mapping", f"0x{obj:04X}:{sub:02X}: {entry.bits} bits")
    if obj == CONTACT and sub not in _CONTACT_COLUMN:
        raise ConfigError("pdo mapping", f"0x{obj:04X}:{sub:02X} is not published")
    column = _CONTACT_COLUMN[sub] if obj == CONTACT else max(sub - 1, 0)
    first = _TABLE.itemsize * (_FIRST_COLUMN[obj] + column)
    return range(first, first + entry.bits // 8)


class Publishing(Protocol):
    """A force node as :func:`batch_frames` uses it (``canbus.master.forcenode.ForceNode``)."""

    def adopt(self, forces_mN: NDArray[np.int16], status: NDArray[np.uint8], valid: int,
              answered: int, contact: ContactBatch | None = None, row: int = 0) -> PdoCodec:
        """Take one sample's object values; the codec to pack them with."""
