"""The host's contact summaries: one :class:`PatchContact` per patch (its geometry, its
thresholds, its state), and :func:`summarize_batch`, which summarises a publishing batch
of many patches at once (:mod:`skin.contact`, :mod:`skin.contact_state`).

A patch's force node holds its :class:`PatchContact` (``ForceNode.contact``): the
publisher summarises each batch right after decoding it, the force node publishes the
summary in its contact objects (0x2008, :mod:`canbus.contact_record`) and the API's
:class:`~canbus.master.channel.ForceFrame` carries it (``contact``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from skin.contact import ContactParams, PatchGeometry, summarize, summarize_rows
from skin.contact_state import (
    NEXT_STATE,
    STATE_BYTE,
    ContactBatch,
    ContactSummary,
    conditions,
    thresholds,
)

_CACHED_LAYOUTS = 64


class PatchContact:
    """One patch's contact judge. ``state`` is its :mod:`skin.contact_state` state."""

    row: tuple[float, ...]
    """Every per-patch number a batch needs; replaced (never changed) on an update."""

    def __init__(self, geometry: PatchGeometry | None = None,
                 params: ContactParams | None = None) -> None:
        self.geometry = geometry or PatchGeometry()
        self.params = params or ContactParams()
        self.state = 0

    @property
    def geometry(self) -> PatchGeometry:
        return self._geometry

    @geometry.setter
    def geometry(self, value: PatchGeometry) -> None:
        self._geometry = value
        self._update_row()

    @property
    def params(self) -> ContactParams:
        return self._params

    @params.setter
    def params(self, value: ContactParams) -> None:
        self._params = value
        self._update_row()

    def _update_row(self) -> None:
        g, p = self.__dict__.get("_geometry"), self.__dict__.get("_params")
        if g is None or p is None:
            return
        theta = math.radians(g.orientation_deg)
        self.row = (g.pitch_m, p.taxel_contact_N, p.onset_N, p.release_N, p.friction,
                    p.near_slip_ratio, *g.position_m, math.cos(theta), math.sin(theta))
        _GENERATION[0] += 1  # every cached batch composition is read anew

    def reset(self) -> None:
        """Forget the history: not in contact, not slipping (a patch that booted again)."""
        self.state = 0


class _Rows:
    """The per-row parameters of one batch composition, as arrays."""

    def __init__(self, rows: Sequence[tuple[float, ...]]) -> None:
        table = np.array(rows, dtype=np.float64)
        (self.pitch, self.threshold, self.onset, self.release, self.friction,
         self.near) = (np.ascontiguousarray(table[:, k]) for k in range(6))
        self.position = np.ascontiguousarray(table[:, 6:8])
        c, s = table[:, 8], table[:, 9]
        self.rotation = np.stack([np.stack([c, -s], axis=1), np.stack([s, c], axis=1)], axis=1)
        self.bounded = bool((self.threshold > 0).all())  # then nothing a decoder gives overflows
        self.limits = thresholds(self.onset, self.release, self.friction, self.near, len(rows))


_GENERATION = [0]
_rows_cache: dict[tuple[int, ...], tuple[int, _Rows]] = {}


def _rows(contacts: Sequence[PatchContact]) -> _Rows:
    """The per-row parameters of this batch composition (cached until a judge changes)."""
    key = tuple(map(id, contacts))
    hit = _rows_cache.get(key)
    generation = _GENERATION[0]
    if hit is not None and hit[0] == generation:
        return hit[1]
    if len(_rows_cache) >= _CACHED_LAYOUTS:
        _rows_cache.clear()
    made = _Rows([c.row for c in contacts])
    _rows_cache[key] = (generation, made)
    return made


class Judged(Protocol):
    """A holder of a patch's contact judge (``canbus.master.forcenode.ForceNode``)."""

    contact: PatchContact | None


def summarize_nodes(nodes: Sequence[Judged], force_N: NDArray[np.float64],
                    valid: NDArray[np.bool_]) -> ContactBatch | None:
    """:func:`summarize_batch` for the patches of force nodes ``nodes`` (row i: node i's);
    None when no node has a contact judge. A node without one is summarised by a judge
    of default thresholds that keeps no state, and gets no summary (:func:`contact_of`)."""
    contacts = [node.contact for node in nodes]
    if all(c is not None for c in contacts):
        return summarize_batch(contacts, force_N, valid)  # type: ignore[arg-type]
    if all(c is None for c in contacts):
        return None
    return summarize_batch([c if c is not None else PatchContact() for c in contacts],
                           force_N, valid)


def contact_rows(batch: ContactBatch | None, nodes: Sequence[Judged]
                 ) -> list[ContactSummary | None]:
    """Every row's summary for the API: None where the node has no contact judge."""
    if batch is None:
        return [None] * len(nodes)
    return [ContactSummary(batch, i) if node.contact is not None else None
            for i, node in enumerate(nodes)]


def summarize_batch(contacts: Sequence[PatchContact], force_N: NDArray[np.float64],
                    valid: NDArray[np.bool_], *, decoded: bool = True) -> ContactBatch:
    """The contact of ``n`` samples, row i of patch ``contacts[i]`` (``(n, 9, 3)`` N and
    ``(n, 9)``), in order; every patch's state is advanced. A patch may appear in several
    rows (cycles queued together): its rows are judged one after the other. ``decoded``:
    the forces are a decoder's as the publisher has them (finite, bounded, 0 where
    invalid); False for any values (checked, and every figure still finite)."""
    rows = _rows(contacts)
    if decoded and rows.bounded:
        instant = summarize_rows(force_N, valid, rows.threshold, rows.pitch, rows.friction,
                                 rows.near, rows.position, rows.rotation)
    else:
        instant = summarize(force_N, valid, pitch_m=rows.pitch, position_m=rows.position,
                            rotation=rows.rotation, taxel_contact_N=rows.threshold,
                            friction=rows.friction, near_slip_ratio=rows.near)
    index = conditions(instant, rows.limits).tolist()
    nxt, table = _NEXT, _BYTE
    out = []
    for contact, i in zip(contacts, index, strict=True):
        k = i + contact.state
        out.append(table[k])
        contact.state = nxt[k]
    return ContactBatch(instant, np.array(out, dtype=np.uint8))


_NEXT, _BYTE = NEXT_STATE.tolist(), STATE_BYTE.tolist()
