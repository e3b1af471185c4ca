"""The host's contact summaries: one :class:`PatchContact` per patch (its geometry, its
thresholds, its state), and :class:`ContactSummarizer`, which summarises a publishing batch
of many patches at once (:mod:`skin.contact`, :mod:`skin.contact_state`).

A patch's force node holds its :class:`PatchContact` (``ForceNode.contact``): the
publisher's summarizer summarises each batch right after decoding it, the force node
publishes the summary in its contact objects (0x2008, :mod:`canbus.contact_record`) and the
API's :class:`~canbus.master.channel.ForceFrame` carries it (``contact``).

A batch's judges, in their order, are its composition: the summarizer keeps what a
composition needs (each row's parameters, the kernel's buffers) until a judge of it is
replaced or takes other parameters, so that a batch like the last costs no set-up.
:func:`summarize_batch` and :func:`summarize_nodes` summarise one batch with nothing kept.
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
    ContactBatch,
    ContactSummary,
    StateTests,
    advance,
    conditions,
    sample_tests,
    tested,
    thresholds,
)
from skin.contact_sums import SumsKernel
from skin.placement import PatchPlacement

COMPOSITIONS_KEPT = 64
"""How many compositions a :class:`ContactSummarizer` keeps (then it starts anew)."""


class PatchContact:
    """One patch's contact judge. ``state`` is its :mod:`skin.contact_state` state."""

    row: tuple[float, ...]
    """Every per-patch number a batch needs; replaced (never changed) when the geometry or
    the thresholds are: a summarizer compares it to tell its compositions still hold."""

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


Judges = tuple[PatchContact | None, ...]
"""A batch composition: row i's judge (None: the row's node has none)."""
Rows = tuple[tuple[float, ...] | None, ...]


class _Composition:
    """The judges of one batch composition and what a batch of them needs: each row's
    parameters (``rows``: the judges' :attr:`PatchContact.row` it was made of; a row with
    no judge is judged by default thresholds), the summary's and the state tests' buffers
    (one batch at a time: ``lock``)."""

    def __init__(self, contacts: Judges, rows: Rows) -> None:
        self.contacts = contacts
        self.rows = rows
        default = PatchContact().row
        table = np.array([default if row is None else row for row in rows],
                         dtype=np.float64).reshape(-1, len(default))
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
        absent = np.array([c is None for c in contacts], dtype=bool)
        self.absent = absent if absent.any() else None
        self.judged = not absent.all()
        self.lock = threading.Lock()


def _rows(contacts: Judges) -> Rows:
    return tuple([None if c is None else c.row for c in contacts])


class Judged(Protocol):
    """A holder of a patch's contact judge (``canbus.master.forcenode.ForceNode``)."""

    contact: PatchContact | None


class ContactSummarizer:
    """Summarises the batches of one publisher (one caller at a time), keeping each batch
    composition it met (module docstring) while its judges are the same objects with the
    same parameters: a judge replaced (``ForceNode.contact``) makes another composition,
    a judge's new geometry or thresholds (a new :attr:`PatchContact.row`) a new one of the
    same judges."""

    def __init__(self, kept: int = COMPOSITIONS_KEPT) -> None:
        self.kept = kept
        self._compositions: dict[Judges, _Composition] = {}

    def nodes(self, nodes: Sequence[Judged], force_N: NDArray[np.float64],
              valid: NDArray[np.bool_]) -> PublishedBatch | None:
        """:meth:`batch` for the patches of force nodes ``nodes`` (row i: node i's) of a
        decoder's forces as the publisher has them; None when no node has a contact judge.
        A node without one is summarised by a judge of default thresholds that keeps no
        state, and gets no summary (``absent``)."""
        composition = self._composition(tuple([node.contact for node in nodes]))
        if not composition.judged:
            return None
        return _judge(composition, force_N, valid, decoded=True, publishing=True)

    def batch(self, contacts: Sequence[PatchContact], force_N: NDArray[np.float64],
              valid: NDArray[np.bool_], *, decoded: bool = True) -> PublishedBatch:
        """The contact of ``n`` samples, row i of patch ``contacts[i]`` (``(n, 9, 3)`` N and
        ``(n, 9)``), in order; every patch's state is advanced. A patch may appear in
        several rows (cycles queued together): its rows are judged one after the other.
        ``decoded``: the forces are a decoder's as the publisher has them (finite, bounded,
        0 where invalid); False for any values (checked, and every figure still finite)."""
        composition = self._composition(tuple(contacts))
        return _judge(composition, force_N, valid, decoded=decoded, publishing=False)

    def _composition(self, contacts: Judges) -> _Composition:
        """The kept composition of ``contacts`` if their rows are still the ones it was
        made of, else a new one (kept in its place)."""
        rows = _rows(contacts)
        kept = self._compositions.get(contacts)
        if kept is not None and kept.rows == rows:
            return kept
        if len(self._compositions) >= self.kept:
            self._compositions.clear()
        made = self._compositions[contacts] = _Composition(contacts, rows)
        return made


def summarize_nodes(nodes: Sequence[Judged], force_N: NDArray[np.float64],
                    valid: NDArray[np.bool_]) -> PublishedBatch | None:
    """:meth:`ContactSummarizer.nodes` of one batch, nothing kept."""
    return ContactSummarizer(kept=1).nodes(nodes, force_N, valid)


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
    """:meth:`ContactSummarizer.batch` of one batch, nothing kept."""
    return ContactSummarizer(kept=1).batch(contacts, force_N, valid, decoded=decoded)


def _judge(composition: _Composition, force_N: NDArray[np.float64],
           valid: NDArray[np.bool_], *, decoded: bool, publishing: bool) -> PublishedBatch:
    """Summarise, then advance each judge's state by one table lookup per row
    (:func:`skin.contact_state.advance`). ``publishing``: the batch goes to the force
    frames next, which take the default PDO's figures as computed here."""
    if not composition.lock.acquire(blocking=False):  # another thread's batch: its own
        composition = _Composition(composition.contacts, composition.rows)
        composition.lock.acquire()
    try:
        published = None
        if decoded and composition.bounded:
            instant = composition.kernel.instant(force_N, valid, bounded=True)
            index = composition.tests.run()
            if publishing and composition.absent is None:
                published = composition.kernel.published, composition.tests.published_defined
        else:
            instant = summarize_rows(np.array(force_N, dtype=np.float64),
                                     np.array(valid, dtype=bool), composition.params)
            index = conditions(sample_tests(tested(instant), composition.limits)).tolist()
    finally:
        composition.lock.release()
    return PublishedBatch(instant, advance(composition.contacts, index), composition.absent,
                          published)
