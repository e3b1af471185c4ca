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
import threading
from collections.abc import Sequence
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from skin.contact import (
    ContactInstant,
    ContactParams,
    PatchGeometry,
    RowParams,
    summarize_rows,
)
from skin.contact_state import (
    DEFINED_TESTS,
    KNOWN_TEST,
    NEXT_STATE,
    STATE_BYTE,
    ContactBatch,
    ContactSummary,
    StateTests,
    conditions,
    sample_tests,
    tested,
    thresholds,
)
from skin.contact_sums import SumsKernel
from skin.placement import PatchPlacement

_CACHED_LAYOUTS = 64


class PatchContact:
    """One patch's contact judge. ``state`` is its :mod:`skin.contact_state` state."""

    row: tuple[float, ...]
    """Every per-patch number a batch needs; replaced (never changed) on an update."""

    def __init__(self, geometry: PatchGeometry | None = None,
                 params: ContactParams | None = None,
                 placement: PatchPlacement | None = None) -> None:
        self.geometry = geometry or PatchGeometry()
        self.params = params or ContactParams()
        self.placement = placement
        """Its link and pose on the robot (None: a flat skin only): the API's frames give
        the summary in the link's frame too (``ForceFrame.on_link``)."""
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
        judges_changed()

    def reset(self) -> None:
        """Forget the history: not in contact, not slipping (a patch that booted again)."""
        self.state = 0


class PublishedBatch(ContactBatch):
    """A publishing batch's contact: :class:`ContactBatch`, the rows that stand for no
    patch's judge (``absent``), and the default contact PDO's figures as the host computed
    them beside the rest (:meth:`take_published`)."""

    __slots__ = ("_published", "absent")

    def __init__(self, instant: ContactInstant, state_byte: NDArray[np.uint8],
                 absent: NDArray[np.bool_] | None = None,
                 published: tuple[NDArray[np.float64], NDArray[np.bool_]] | None = None
                 ) -> None:
        super().__init__(instant, state_byte)
        self.absent = absent
        """(n,) rows that stand for no patch's judge (they get no summary); None: none."""
        self._published = published

    def take_published(self) -> tuple[NDArray[np.float64], NDArray[np.bool_]] | None:
        """The figures of :data:`canbus.contact_record.PUBLISHED` (``(3, n)`` CoP y, CoP x,
        net Fz in SI units) and where they have a value, as the host computed them: views
        of its buffers, good until its next batch, so given once (then None: encode them
        from the summary)."""
        published, self._published = self._published, None
        return published


class _Composition:
    """The judges of one batch composition (row i: the judge of its i-th patch, None: no
    judge) and what a batch of them needs: each row's parameters, the summary's and the
    state tests' buffers (one batch at a time: ``lock``)."""

    def __init__(self, contacts: Sequence[PatchContact | None]) -> None:
        self.contacts = list(contacts)
        table = np.array([_DEFAULT_ROW if c is None else c.row for c in contacts],
                         dtype=np.float64).reshape(-1, len(_DEFAULT_ROW))
        pitch, threshold, onset, release, friction, near = (
            np.ascontiguousarray(table[:, k]) for k in range(6))
        c, s = table[:, 8], table[:, 9]
        rotation = np.stack([np.stack([c, -s], axis=1), np.stack([s, c], axis=1)], axis=1)
        self.params = RowParams(threshold, pitch, friction, near,
                                np.ascontiguousarray(table[:, 6:8]), rotation)
        self.bounded = bool((threshold > 0).all())  # then nothing a decoder gives overflows
        self.limits = thresholds(onset, release, friction, near, len(table))
        self.kernel = SumsKernel(self.params)
        self.tests = StateTests(self.kernel.tested, self.limits)
        self.has = self.tests.said[DEFINED_TESTS.start:KNOWN_TEST + 1]
        absent = np.array([c is None for c in contacts], dtype=bool)
        self.absent = absent if absent.any() else None
        self.judged = not absent.all()
        self.lock = threading.Lock()


_GENERATION = [0]
_by_judges: dict[tuple[int, ...], tuple[int, _Composition]] = {}
_by_nodes: dict[tuple[int, ...], tuple[int, _Composition]] = {}


def judges_changed() -> None:
    """Read every batch composition anew: a judge was made, updated or replaced."""
    _GENERATION[0] += 1


_DEFAULT_ROW = PatchContact().row


def _cached(cache: dict[tuple[int, ...], tuple[int, _Composition]], key: tuple[int, ...],
            contacts: Sequence[PatchContact | None] | None = None,
            holders: Sequence[Judged] = ()) -> _Composition:
    """The composition cached under ``key`` (until a judge changes), else a new one of
    ``contacts`` (or of the ``holders``' judges)."""
    hit = cache.get(key)
    generation = _GENERATION[0]
    if hit is not None and hit[0] == generation:
        return hit[1]
    if len(cache) >= _CACHED_LAYOUTS:
        cache.clear()
    made = _Composition(contacts if contacts is not None else [h.contact for h in holders])
    cache[key] = (generation, made)
    return made


class Judged(Protocol):
    """A holder of a patch's contact judge (``canbus.master.forcenode.ForceNode``)."""

    contact: PatchContact | None


def summarize_nodes(nodes: Sequence[Judged], force_N: NDArray[np.float64],
                    valid: NDArray[np.bool_]) -> PublishedBatch | None:
    """:func:`summarize_batch` for the patches of force nodes ``nodes`` (row i: node i's) of
    a decoder's forces as the publisher has them; None when no node has a contact judge. A
    node without one is summarised by a judge of default thresholds that keeps no state,
    and gets no summary (``absent``)."""
    composition = _cached(_by_nodes, tuple(map(id, nodes)), holders=nodes)
    if not composition.judged:
        return None
    return _judge(composition, force_N, valid, decoded=True, publishing=True)


def contact_rows(batch: PublishedBatch | None, nodes: Sequence[Judged]
                 ) -> list[ContactSummary | None]:
    """Every row's summary for the API: None where the node has no contact judge."""
    if batch is None:
        return [None] * len(nodes)
    if batch.absent is None:
        return list(batch.rows())
    return [None if gone else ContactSummary(batch, i)
            for i, gone in enumerate(batch.absent.tolist())]


def summarize_batch(contacts: Sequence[PatchContact], force_N: NDArray[np.float64],
                    valid: NDArray[np.bool_], *, decoded: bool = True) -> PublishedBatch:
    """The contact of ``n`` samples, row i of patch ``contacts[i]`` (``(n, 9, 3)`` N and
    ``(n, 9)``), in order; every patch's state is advanced. A patch may appear in several
    rows (cycles queued together): its rows are judged one after the other. ``decoded``:
    the forces are a decoder's as the publisher has them (finite, bounded, 0 where
    invalid); False for any values (checked, and every figure still finite)."""
    composition = _cached(_by_judges, tuple(map(id, contacts)), contacts)
    return _judge(composition, force_N, valid, decoded=decoded, publishing=False)


def _judge(composition: _Composition, force_N: NDArray[np.float64],
           valid: NDArray[np.bool_], *, decoded: bool, publishing: bool) -> PublishedBatch:
    """Summarise, then advance each judge's state by one table lookup per row (None: no
    judge, the state of a patch never seen, kept by no one). ``publishing``: the batch goes
    to ``batch_frames`` next, which takes the default PDO's figures as computed here."""
    if not composition.lock.acquire(blocking=False):  # another thread's batch: its own
        composition = _Composition(composition.contacts)
        composition.lock.acquire()
    try:
        published = None
        if decoded and composition.bounded:
            instant = composition.kernel.instant(force_N, valid, bounded=True)
            index = composition.tests.run()
            if publishing and composition.absent is None:
                published = composition.kernel.published, composition.has
        else:
            instant = summarize_rows(np.array(force_N, dtype=np.float64),
                                     np.array(valid, dtype=bool), composition.params)
            index = conditions(sample_tests(tested(instant), composition.limits)).tolist()
    finally:
        composition.lock.release()
    nxt, table = _NEXT, _BYTE
    out = []
    for contact, i in zip(composition.contacts, index, strict=True):
        if contact is None:
            out.append(table[i])
            continue
        k = i + contact.state
        out.append(table[k])
        contact.state = nxt[k]
    return PublishedBatch(instant, np.array(out, dtype=np.uint8), composition.absent,
                          published)


_NEXT, _BYTE = NEXT_STATE.tolist(), STATE_BYTE.tolist()
