"""A patch's contact over time: in contact with hysteresis, onset and release, slipping.

:func:`step` advances the state of ``n`` patches by one sample each (the host's batches);
:func:`track` runs one patch through a sequence of samples (the simulator's truth, the
benchmark). Both look the next state and the sample's state byte up in one table, built
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

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skin.constants import TAXELS_PER_PATCH
from skin.contact import F64, SMALLEST_N, Bools, ContactInstant, ContactParams

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
_WEIGHTS = 1 << np.arange(2, 9)
_SOURCES = np.array([0, 0, 1, 1, 2, 0, 2])  # net Fz, ratio, valid taxels -> the 7 tests


def thresholds(onset_N: ArrayLike, release_N: ArrayLike, friction: ArrayLike,
               near_slip_ratio: ArrayLike, n: int) -> F64:
    """``(n, 7)``: what :func:`conditions` compares each sample with."""
    columns = (onset_N, release_N, friction, near_slip_ratio, 1.0, SMALLEST_N,
               float(TAXELS_PER_PATCH))
    return np.column_stack([np.broadcast_to(np.asarray(c, dtype=np.float64), (n,))
                            for c in columns])


def conditions(instant: ContactInstant, limits: F64) -> NDArray[np.intp]:
    """(n,) what each sample says, as bits 2-8 of an index into the tables (the state goes
    in bits 0-1): its net Fz, tangential ratio and valid taxels against ``limits``
    (:func:`thresholds`)."""
    values = np.empty((len(instant), 3))
    values[:, 0] = instant.force_N[:, 2]
    values[:, 1] = instant.tangential_ratio
    values[:, 2] = instant.valid_taxels
    out: NDArray[np.intp] = (values[:, _SOURCES] >= limits) @ _WEIGHTS
    return out


class ContactBatch:
    """``n`` samples' contact: what each says (``instant``) and its state byte (the bits
    above), from which the state's fields are read."""

    __slots__ = ("_flags", "instant", "state_byte")

    def __init__(self, instant: ContactInstant, state_byte: NDArray[np.uint8]) -> None:
        self.instant = instant
        self.state_byte = state_byte  # (n,)
        self._flags: dict[int, Bools] = {}

    def __len__(self) -> int:
        return len(self.instant)

    def _flag(self, bit: int) -> Bools:
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
        return [ContactSummary(self, i) for i in range(len(self))]


def step(state: ArrayLike, instant: ContactInstant, *, onset_N: F64 | float,
         release_N: F64 | float, friction: F64 | float, near_slip_ratio: F64 | float
         ) -> tuple[State, ContactBatch]:
    """One sample of each of ``n`` patches: their new state and their :class:`ContactBatch`.

    ``state`` ``(n,)`` (0 for a patch never seen); the thresholds scalars or ``(n,)``.
    """
    limits = thresholds(onset_N, release_N, friction, near_slip_ratio, len(instant))
    index = conditions(instant, limits) + np.asarray(state, dtype=np.intp)
    return NEXT_STATE[index], ContactBatch(instant, STATE_BYTE[index])


def track(instant: ContactInstant, params: ContactParams, state: int = 0
          ) -> tuple[int, ContactBatch]:
    """One patch's ``n`` consecutive samples, in order, from ``state``: the state after
    the last one and every sample's :class:`ContactBatch` row."""
    limits = thresholds(params.onset_N, params.release_N, params.friction,
                        params.near_slip_ratio, len(instant))
    return sequence(conditions(instant, limits).tolist(), state, instant)


def sequence(index: list[int], state: int, instant: ContactInstant) -> tuple[int, ContactBatch]:
    """The samples of one patch one after the other (each one's state is the last's)."""
    nxt, table = NEXT_STATE.tolist(), STATE_BYTE.tolist()
    out = []
    for i in index:
        out.append(table[i + state])
        state = nxt[i + state]
    return state, ContactBatch(instant, np.array(out, dtype=np.uint8))


class ContactSummary:
    """One patch-sample's contact (a view of a :class:`ContactBatch` row).

    Forces in N, torques in N·m, positions in m; the CoP is 0 (placed: the patch's
    position) where ``cop_defined`` is False. ``partial``: some taxel was invalid, the
    figures rest on the others; ``unknown``: none was valid, every figure is 0 and the
    contact state is the one held from before.
    """

    __slots__ = ("_batch", "_i")

    def __init__(self, batch: ContactBatch, i: int) -> None:
        self._batch = batch
        self._i = i

    @property
    def force_N(self) -> F64:
        out: F64 = self._batch.instant.force_N[self._i]
        return out

    @property
    def torque_Nm(self) -> F64:
        out: F64 = self._batch.instant.torque_Nm[self._i]
        return out

    @property
    def cop_m(self) -> F64:
        out: F64 = self._batch.instant.cop_m[self._i]
        return out

    @property
    def cop_placed_m(self) -> F64:
        out: F64 = self._batch.instant.cop_placed_m[self._i]
        return out

    @property
    def force_placed_N(self) -> F64:
        out: F64 = self._batch.instant.force_placed_N[self._i]
        return out

    @property
    def cop_defined(self) -> bool:
        return bool(self._batch.instant.cop_defined[self._i])

    @property
    def contact_taxels(self) -> Bools:
        out: Bools = self._batch.instant.contact_taxels[self._i]
        return out

    @property
    def taxels_in_contact(self) -> int:
        return int(self._batch.instant.taxels_in_contact[self._i])

    @property
    def contact_area_m2(self) -> float:
        """The taxels in contact times pitch²: the area the contact covers, to a taxel."""
        return float(self._batch.instant.contact_area_m2[self._i])

    @property
    def valid_taxels(self) -> int:
        return int(self._batch.instant.valid_taxels[self._i])

    @property
    def partial(self) -> bool:
        return self.valid_taxels < TAXELS_PER_PATCH

    @property
    def unknown(self) -> bool:
        return self.valid_taxels == 0

    @property
    def tangential_ratio(self) -> float:
        return float(self._batch.instant.tangential_ratio[self._i])

    @property
    def taxel_slip(self) -> Bools:
        out: Bools = self._batch.instant.taxel_slip[self._i]
        return out

    @property
    def taxel_near_slip(self) -> Bools:
        out: Bools = self._batch.instant.taxel_near_slip[self._i]
        return out

    @property
    def in_contact(self) -> bool:
        return bool(self._batch.in_contact[self._i])

    @property
    def onset(self) -> bool:
        return bool(self._batch.onset[self._i])

    @property
    def release(self) -> bool:
        return bool(self._batch.release[self._i])

    @property
    def slipping(self) -> bool:
        return bool(self._batch.slipping[self._i])

    @property
    def slip_onset(self) -> bool:
        return bool(self._batch.slip_onset[self._i])

    @property
    def near_slip(self) -> bool:
        return bool(self._batch.near_slip[self._i])

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
