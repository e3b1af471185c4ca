"""One node's PDOs of one sample, joined: the rules of :mod:`canbus.tools.pdo_samples`.

:class:`PdoAssembly` holds one node's mapping (:class:`~canbus.pdo_codec.TpdoLayout` s, of
any length up to CAN FD's 64 bytes) and the sample being assembled: each frame's bytes go
into a preallocated buffer at its PDO's place; when the sample closes, one
``np.frombuffer`` with a structured dtype reads every mapped variable. Where a sample
begins and closes: the module docstring of :mod:`canbus.tools.pdo_samples` (a force
node's samples; a patch's answers: :class:`~canbus.tools.patch_answers.PatchAnswers`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import canopen
import numpy as np
from numpy.typing import NDArray

from canbus.pdo_codec import TpdoLayout, entry_dtype

HEADLESS_SHARE = 0.8
"""Of the period: how long a sample without its first PDO may stay open."""
OPEN_PERIODS = 2.0
"""Periods after which any open sample closes partial."""


@dataclass(frozen=True)
class Variable:
    """A mapped object ``index:subindex`` and the PDO (bit in ``arrived``) that carries it."""

    index: int
    subindex: int
    pdo: int


@dataclass(frozen=True)
class JoinedPdos:
    """One node's joined PDOs (read them with :meth:`PdoAssembly.values`)."""

    node_id: int
    timestamp: float  # bus time of the sample's last PDO
    payload: bytes  # the PDOs at their places in the assembly's buffer
    arrived: int  # bit p: PDO p (in ``PdoAssembly.layouts`` order) came
    complete: bool  # every mapped PDO came, once
    cycle: int | None = None  # the SYNC cycle a patch's answer is of (patch_answers)


class PdoAssembly:
    """One node's TPDO mapping and the sample being assembled (not thread-safe)."""

    def __init__(self, node_id: int, layouts: Sequence[TpdoLayout],
                 od: canopen.ObjectDictionary, *, order: str = "cob-id") -> None:
        self.node_id = node_id
        self.layouts = tuple(layouts)
        self.slots: dict[int, tuple[int, int, int]] = {}  # COB-ID -> (PDO bit, offset, size)
        formats: list[np.dtype[np.generic]] = []
        offsets: list[int] = []
        variables: list[Variable] = []
        taken: set[tuple[int, int]] = set()
        at = 0
        for bit, layout in enumerate(self.layouts):
            self.slots[layout.cob_id] = (bit, at, layout.size)
            offset = at
            for entry in layout.entries:
                key = (entry.index, entry.subindex)
                # index < 0x1000: CiA 301's dummy entries (a data type), padding only
                if entry.index >= 0x1000 and key not in taken:
                    taken.add(key)
                    formats.append(entry_dtype(entry, od))
                    offsets.append(offset)
                    variables.append(Variable(entry.index, entry.subindex, bit))
                offset += entry.bits // 8
            at += max(8, layout.size)
        self.variables = tuple(variables)
        self.size = max(at, 1)
        self.buffer = bytearray(self.size)
        by_dtype: dict[np.dtype[np.generic], list[int]] = {}
        for k, dtype in enumerate(formats):
            by_dtype.setdefault(dtype, []).append(k)
        self._groups = [(dtype, np.array(cols, dtype=np.intp),
                         np.array([offsets[k] + b for k in cols for b in range(dtype.itemsize)],
                                  dtype=np.intp))
                        for dtype, cols in by_dtype.items()]
        self._pdo = np.array([v.pdo for v in variables], dtype=np.int64)
        self.full = (1 << len(self.layouts)) - 1
        cob_ids = [layout.cob_id for layout in self.layouts]
        self.first_pdo = 0 if not cob_ids or order == "tpdo" else cob_ids.index(min(cob_ids))
        self.last_pdo = -1
        self.await_first = False
        """Take nothing before the node's first PDO (it was named mid-sample)."""
        self.seen = 0
        self.first = 0.0
        self.last = 0.0
        self.malformed = 0

    def column(self, index: int, subindex: int) -> int | None:
        for k, v in enumerate(self.variables):
            if (v.index, v.subindex) == (index, subindex):
                return k
        return None

    def take(self, cob_id: int, data: bytes, timestamp: float,
             period_s: float) -> list[JoinedPdos]:
        """One frame of PDO ``cob_id``: the samples it closes (none, one or two)."""
        bit, offset, size = self.slots[cob_id]
        out: list[JoinedPdos] = []
        if self.await_first:
            if bit != self.first_pdo:
                return out  # the rest of a sample whose beginning was not the node's yet
            self.await_first = False
        if self.seen:
            if bit == self.first_pdo:
                out.append(self.close())
            elif self.seen >> bit & 1:
                if bit == self.last_pdo and bytes(data[:size]) == \
                        self.buffer[offset:offset + size]:
                    return out  # the frame just taken, again: a retransmission seen twice
                out.append(self.close())
            elif not self.seen >> self.first_pdo & 1 and \
                    timestamp - self.first > HEADLESS_SHARE * period_s:
                out.append(self.close())
        if len(data) < size:
            self.malformed += 1  # not trusted: its PDO stays missing
            return out
        if not self.seen:
            self.first = timestamp
        self.buffer[offset:offset + size] = data[:size]
        self.seen |= 1 << bit
        self.last = timestamp
        self.last_pdo = bit
        if self.seen == self.full:
            out.append(self.close())
        return out

    def expire(self, now: float, period_s: float) -> JoinedPdos | None:
        """The open sample, closed partial, if it has been open for :data:`OPEN_PERIODS`
        periods by bus time ``now`` (:data:`HEADLESS_SHARE` of one without its first PDO)."""
        if not self.seen:
            return None
        limit = OPEN_PERIODS if self.seen >> self.first_pdo & 1 else HEADLESS_SHARE
        if now - self.first > limit * period_s:
            return self.close()
        return None

    def sync(self, counter: int, timestamp: float) -> list[JoinedPdos]:
        """A SYNC: the samples it closes (none: a sample here is closed by its PDOs)."""
        return []

    def finish(self) -> list[JoinedPdos]:
        """The bus or the recording ended: the samples that closes (none here)."""
        return []

    def close(self) -> JoinedPdos:
        sample = JoinedPdos(self.node_id, self.last, bytes(self.buffer), self.seen,
                           self.seen == self.full)
        self.seen = 0
        return sample

    def values(self, samples: Sequence[JoinedPdos]) -> NDArray[np.float64]:
        """``(n, V)`` every mapped variable of ``n`` samples of this assembly, one numpy
        read; a PDO that did not come reads as the bytes left by the last one that did."""
        n = len(samples)
        raw = np.frombuffer(b"".join(s.payload for s in samples), dtype=np.uint8)
        raw = raw.reshape(n, self.size)
        out = np.empty((n, len(self.variables)), dtype=np.float64)
        for dtype, columns, byte_index in self._groups:
            out[:, columns] = np.ascontiguousarray(raw[:, byte_index]).view(dtype)
        return out

    def arrived(self, samples: Sequence[JoinedPdos]) -> NDArray[np.bool_]:
        """``(n, V)`` whether each variable's PDO came."""
        bits = np.array([s.arrived for s in samples], dtype=np.int64)
        came: NDArray[np.bool_] = (bits[:, None] >> self._pdo[None, :] & 1).astype(bool)
        return came
