"""A patch's contact over time: in contact with hysteresis, onset and release, slipping.

:func:`step` advances the state of ``n`` patches by one sample each; :func:`advance` does it
for the host's batches, whose patches keep their states in their contact judges;
:func:`track` runs one patch through a sequence of samples (the simulator's truth, the
benchmark). All look the next state and the sample's state byte up in one table, built
from the rules below by :func:`_tables`, indexed by the state and what the sample says.
The state of a patch is one small integer (bit 0 in contact, bit 1 slipping):

- in contact from the sample whose net normal force (over the taxels in contact) reaches
  ``onset_N`` until the one where it falls below ``release_N``; ``onset`` and ``release``
  mark those samples;
- slipping while in contact, from the sample whose tangential ratio reaches μ until the one
  where it falls below (1 − margin)·μ (the near-slip band is its hysteresis); ``slip_onset``
  marks the first;
- a sample with no valid taxel (``unknown``) changes nothing: the state is held, and no
  event is reported, until a sample says something again.

:class:`ContactSummary` is one patch-sample's summary as the API gives it: a view of one
row of a :class:`ContactBatch`, built without copying.
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Iterable
from typing import Any, NamedTuple, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skin.constants import TAXELS_PER_PATCH
from skin.contact import F64, Bools, ContactInstant, ContactParams
from skin.contact_sums import FZ

IN_CONTACT, SLIPPING = 1, 2
"""The state's bits."""
CONTACT_BIT, ONSET, RELEASE, NEAR_SLIP, SLIP_BIT, SLIP_ONSET, PARTIAL, UNKNOWN = (
    1 << k for k in range(8))
"""The bits of a sample's state byte (:attr:`ContactBatch.state_byte`): in contact, contact
onset, release, near slip, slipping, slip onset, partial (some taxel invalid), unknown (no
valid taxel). It is the byte a force node publishes (0x2008 sub-index 11)."""
State = NDArray[np.uint8]


def _tables() -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """The next state and the state byte for every (state, conditions) index: bits 0-1 the
    state, then what the sample says (:func:`conditions`): 2 net Fz >= onset, 3 net Fz >=
    release, 4 ratio >= μ, 5 ratio >= (1 - margin)·μ, 6 a valid taxel, 7 a taxel in contact,
    8 every taxel valid."""
    nxt = np.zeros(512, dtype=np.uint8)
    byte = np.zeros(512, dtype=np.uint8)
    for index in range(512):
        was, was_slipping = bool(index & 1), bool(index & 2)
        enter, stay, cone, near, known, defined, whole = (
            bool(index >> b & 1) for b in range(2, 9))
        now = (stay if was else enter) if known else was
        judged = known and defined
        slipping = now and ((near if was_slipping else cone) if judged else was_slipping)
        nxt[index] = now * IN_CONTACT + slipping * SLIPPING
        flags = (now, now and not was, was and not now, now and judged and near, slipping,
                 slipping and not was_slipping, not whole, not known)
        byte[index] = sum(1 << k for k, on in enumerate(flags) if on)
    return nxt, byte


NEXT_STATE, STATE_BYTE = _tables()
_NEXT, _BYTE = tuple(NEXT_STATE.tolist()), tuple(STATE_BYTE.tolist())
"""The tables as Python ints: a lookup per row without numpy's cost per call."""
TESTS = 12
"""What a sample says, as :func:`sample_tests` lays it out: ``(4, 3, n)`` flattened to ``(12, n)``,
three tests on each of net Fz, the taxels in contact, the valid taxels and the ratio (the
rows of :attr:`~skin.contact_sums.SumsKernel.tested`)."""
DEFINED_TESTS, KNOWN_TEST = slice(4, 6), 6
"""The tests "a taxel in contact" (twice) and "a valid taxel", adjacent: what the CoP and
the net force of the default contact PDO need to have a value."""
_WEIGHTS = np.zeros(TESTS, dtype=np.intp)
_WEIGHTS[[0, 1, 9, 10, KNOWN_TEST, 5, 7]] = 4, 8, 16, 32, 64, 128, 256
"""Each test's bit in a table index (:func:`_tables`): net Fz >= onset, release; ratio >=
μ, (1 - margin)·μ; valid taxels >= 1; taxels in contact >= 1; valid taxels >= 9."""


def thresholds(onset_N: ArrayLike, release_N: ArrayLike, friction: ArrayLike,
               near_slip_ratio: ArrayLike, n: int) -> F64:
    """``(4, 3, n)``: what :func:`sample_tests` compares each sample's net Fz (with onset,
    release), taxels in contact (1, twice), valid taxels (1, 9) and ratio (μ, (1 -
    margin)·μ) with; +inf where nothing is tested."""
    out = np.full((4, 3, n), np.inf)
    out[0, 0] = onset_N
    out[0, 1] = release_N
    out[1, 1:] = 1.0
    out[2, 0] = 1.0
    out[2, 1] = float(TAXELS_PER_PATCH)
    out[3, 0] = friction
    out[3, 1] = near_slip_ratio
    return out


def tested(instant: ContactInstant) -> F64:
    """``(4, 1, n)`` the figures the tests read (the sums' net Fz, taxels in contact, valid
    taxels and ratio)."""
    out: F64 = instant.sums[FZ:, None, :, 0]
    return out


def sample_tests(figures: F64, limits: F64) -> Bools:
    """``(12, n)`` what each sample says: ``figures`` (:func:`tested`) against ``limits``
    (:func:`thresholds`), in one comparison."""
    said: Bools = np.greater_equal(figures, limits)
    return said.reshape(TESTS, -1)


def conditions(said: Bools) -> NDArray[np.intp]:
    """(n,) the tests as bits 2-8 of an index into the tables (the state goes in bits 0-1)."""
    index: NDArray[np.intp] = np.matmul(_WEIGHTS, said)
    return index


class StateTests:
    """:func:`sample_tests` and :func:`conditions` of ``n`` rows into buffers of their own, on
    ``figures`` (a view the summary fills anew for every batch)."""

    def __init__(self, figures: F64, limits: F64) -> None:
        self._figures = figures
        self._limits = limits
        self._said = np.empty(limits.shape, dtype=bool)
        self.said = self._said.reshape(TESTS, -1)
        """(12, n) what the last batch said (:func:`sample_tests`)."""
        self.published_defined = self.said[DEFINED_TESTS.start:KNOWN_TEST + 1]
        """(3, n) where the last batch's CoP y, CoP x and net Fz have a value (a taxel in
        contact, twice; a valid taxel): the default contact PDO's figures, in the order of
        :attr:`~skin.contact_sums.SumsKernel.published`."""
        self._index = np.empty(limits.shape[-1], dtype=np.intp)

    def run(self) -> list[int]:
        """Each row's table index (without its state) for what ``figures`` hold now."""
        np.greater_equal(self._figures, self._limits, out=self._said)
        index: list[int] = np.matmul(_WEIGHTS, self.said, out=self._index).tolist()
        return index


class HeldState(Protocol):
    """Whatever keeps a patch's state between batches (the host's contact judge)."""

    state: int


def advance(holders: Iterable[HeldState | None], index: Iterable[int]) -> State:
    """Each row's state byte, from its table index without the state (:meth:`StateTests.run`,
    :func:`conditions`) and the state of its holder, whose state moves on; None: a patch
    never seen, whose state no one keeps. Rows go in order, so a holder on several rows
    (samples of one patch queued together) takes them one after the other."""
    nxt, table = _NEXT, _BYTE
    out = []
    for holder, i in zip(holders, index, strict=True):
        if holder is None:
            out.append(table[i])
            continue
        k = i + holder.state
        out.append(table[k])
        holder.state = nxt[k]
    return np.array(out, dtype=np.uint8)


class ContactBatch:
    """``n`` samples' contact: what each says (``instant``) and its state byte (the bits
    above), from which the state's fields are read."""

    __slots__ = ("_flags", "instant", "state_byte")

    def __init__(self, instant: ContactInstant, state_byte: NDArray[np.uint8]) -> None:
        self.instant = instant
        self.state_byte = state_byte  # (n,)
        self._flags: dict[int, Bools] | None = None

    def __len__(self) -> int:
        return len(self.instant)

    def _flag(self, bit: int) -> Bools:
        if self._flags is None:
            self._flags = {}
        flag = self._flags.get(bit)
        if flag is None:
            flag = self._flags[bit] = (self.state_byte & bit) != 0
        return flag

    @property
    def in_contact(self) -> Bools:
        return self._flag(CONTACT_BIT)

    @property
    def onset(self) -> Bools:
        """(n,) contact began at this sample."""
        return self._flag(ONSET)

    @property
    def release(self) -> Bools:
        """(n,) contact ended at this sample."""
        return self._flag(RELEASE)

    @property
    def near_slip(self) -> Bools:
        """(n,) in contact and the ratio within the margin of μ, or beyond."""
        return self._flag(NEAR_SLIP)

    @property
    def slipping(self) -> Bools:
        return self._flag(SLIP_BIT)

    @property
    def slip_onset(self) -> Bools:
        """(n,) slipping began at this sample."""
        return self._flag(SLIP_ONSET)

    def row(self, i: int) -> ContactSummary:
        return ContactSummary(self, i)

    def rows(self) -> list[ContactSummary]:
        return list(map(_summary, zip(itertools.repeat(self), range(len(self)))))


def step(state: ArrayLike, instant: ContactInstant, *, onset_N: F64 | float,
         release_N: F64 | float, friction: F64 | float, near_slip_ratio: F64 | float
         ) -> tuple[State, ContactBatch]:
    """One sample of each of ``n`` patches: their new state and their :class:`ContactBatch`.

    ``state`` ``(n,)`` (0 for a patch never seen); the thresholds scalars or ``(n,)``.
    """
    limits = thresholds(onset_N, release_N, friction, near_slip_ratio, len(instant))
    said = sample_tests(tested(instant), limits)
    index = conditions(said) + np.asarray(state, dtype=np.intp)
    return NEXT_STATE[index], ContactBatch(instant, STATE_BYTE[index])


def track(instant: ContactInstant, params: ContactParams, state: int = 0
          ) -> tuple[int, ContactBatch]:
    """One patch's ``n`` consecutive samples, in order, from ``state``: the state after
    the last one and every sample's :class:`ContactBatch` row."""
    limits = thresholds(params.onset_N, params.release_N, params.friction,
                        params.near_slip_ratio, len(instant))
    nxt, table = _NEXT, _BYTE
    out = []
    for i in conditions(sample_tests(tested(instant), limits)).tolist():
        out.append(table[i + state])
        state = nxt[i + state]
    return state, ContactBatch(instant, np.array(out, dtype=np.uint8))


class ContactSummary(NamedTuple):
    """One patch-sample's contact: row ``row`` of ``batch``, read from it when asked.

    Forces in N, torques in N·m, positions in m; the CoP is 0 (placed: the patch's
    position) where ``cop_defined`` is False. ``partial``: some taxel was invalid, the
    figures rest on the others; ``unknown``: none was valid, every figure is 0 and the
    contact state is the one held from before. A pair, so that the host makes a batch's
    summaries at the cost of tuples (:meth:`ContactBatch.rows`).
    """

    batch: ContactBatch
    row: int

    @property
    def force_N(self) -> F64:
        out: F64 = self.batch.instant.force_N[self.row]
        return out

    @property
    def torque_Nm(self) -> F64:
        out: F64 = self.batch.instant.torque_Nm[self.row]
        return out

    @property
    def cop_m(self) -> F64:
        out: F64 = self.batch.instant.cop_m[self.row]
        return out

    @property
    def cop_placed_m(self) -> F64:
        out: F64 = self.batch.instant.cop_placed_m[self.row]
        return out

    @property
    def force_placed_N(self) -> F64:
        out: F64 = self.batch.instant.force_placed_N[self.row]
        return out

    @property
    def cop_defined(self) -> bool:
        return bool(self.batch.instant.cop_defined[self.row])

    @property
    def contact_taxels(self) -> Bools:
        out: Bools = self.batch.instant.contact_taxels[self.row]
        return out

    @property
    def taxels_in_contact(self) -> int:
        return int(self.batch.instant.taxels_in_contact[self.row])

    @property
    def contact_area_m2(self) -> float:
        """The taxels in contact times pitch²: the area the contact covers, to a taxel."""
        return float(self.batch.instant.contact_area_m2[self.row])

    @property
    def valid_taxels(self) -> int:
        return int(self.batch.instant.valid_taxels[self.row])

    @property
    def partial(self) -> bool:
        return self.valid_taxels < TAXELS_PER_PATCH

    @property
    def unknown(self) -> bool:
        return self.valid_taxels == 0

    @property
    def tangential_ratio(self) -> float:
        return float(self.batch.instant.tangential_ratio[self.row])

    @property
    def taxel_slip(self) -> Bools:
        out: Bools = self.batch.instant.taxel_slip[self.row]
        return out

    @property
    def taxel_near_slip(self) -> Bools:
        out: Bools = self.batch.instant.taxel_near_slip[self.row]
        return out

    @property
    def in_contact(self) -> bool:
        return bool(self.batch.in_contact[self.row])

    @property
    def onset(self) -> bool:
        return bool(self.batch.onset[self.row])

    @property
    def release(self) -> bool:
        return bool(self.batch.release[self.row])

    @property
    def slipping(self) -> bool:
        return bool(self.batch.slipping[self.row])

    @property
    def slip_onset(self) -> bool:
        return bool(self.batch.slip_onset[self.row])

    @property
    def near_slip(self) -> bool:
        return bool(self.batch.near_slip[self.row])

    def to_dict(self) -> dict[str, Any]:
        """Plain Python values (JSON-ready): every field."""
        return {
            "force_N": self.force_N.tolist(), "torque_Nm": self.torque_Nm.tolist(),
            "cop_m": self.cop_m.tolist(), "cop_placed_m": self.cop_placed_m.tolist(),
            "force_placed_N": self.force_placed_N.tolist(), "cop_defined": self.cop_defined,
            "contact_taxels": self.contact_taxels.tolist(),
            "taxels_in_contact": self.taxels_in_contact,
            "contact_area_m2": self.contact_area_m2, "valid_taxels": self.valid_taxels,
            "partial": self.partial, "unknown": self.unknown,
            "tangential_ratio": self.tangential_ratio, "in_contact": self.in_contact,
            "onset": self.onset, "release": self.release, "near_slip": self.near_slip,
            "slipping": self.slipping, "slip_onset": self.slip_onset,
            "taxel_slip": self.taxel_slip.tolist(),
            "taxel_near_slip": self.taxel_near_slip.tolist()}

    def __repr__(self) -> str:
        fz = self.force_N[2]
        where = (f"cop=({1000 * self.cop_m[0]:+.2f}, {1000 * self.cop_m[1]:+.2f}) mm"
                 if self.cop_defined else "cop=none")
        state = "slipping" if self.slipping else "contact" if self.in_contact else "free"
        return (f"ContactSummary(fz={fz:.3f} N, {where}, {state}, "
                f"taxels={self.taxels_in_contact}, valid={self.valid_taxels})")


_summary = functools.partial(tuple.__new__, ContactSummary)
"""A :class:`ContactSummary` of a ``(batch, row)`` pair, made by the tuple type itself."""
