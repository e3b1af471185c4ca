"""A patch's contact over time: in contact with hysteresis, onset and release, slipping.

:func:`step` advances the state of ``n`` patches by one sample each (the host's batches);
:func:`track` runs one patch through a sequence of samples (the simulator's truth, the
benchmark). The state of a patch is one small integer (bit 0 in contact, bit 1 slipping):

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

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skin.constants import TAXELS_PER_PATCH
from skin.contact import F64, Bools, ContactInstant, ContactParams

IN_CONTACT, SLIPPING = 1, 2
State = NDArray[np.uint8]


@dataclass(frozen=True)
class ContactBatch:
    """``n`` samples' contact: what each says (``instant``) and the state it leaves."""

    instant: ContactInstant
    in_contact: Bools  # (n,)
    onset: Bools  # (n,) contact began at this sample
    release: Bools  # (n,) contact ended at this sample
    slipping: Bools  # (n,)
    slip_onset: Bools  # (n,) slipping began at this sample
    near_slip: Bools  # (n,) in contact and the ratio within the margin of μ (or beyond)

    def __len__(self) -> int:
        return len(self.instant)

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
    prev = np.asarray(state, dtype=np.uint8)
    was = (prev & IN_CONTACT).astype(bool)
    was_slipping = (prev & SLIPPING).astype(bool)
    known = instant.valid_taxels > 0
    fz = instant.force_N[:, 2]
    now = np.where(known, np.where(was, fz >= release_N, fz >= onset_N), was)
    ratio = instant.tangential_ratio
    cone = np.where(was_slipping, ratio >= near_slip_ratio, ratio >= friction)
    judged = known & instant.cop_defined
    slipping = now & np.where(judged, cone, was_slipping)
    new = (now * IN_CONTACT + slipping * SLIPPING).astype(np.uint8)
    return new, ContactBatch(instant, now, now & ~was, was & ~now, slipping,
                             slipping & ~was_slipping, now & judged & instant.near_slip)


def track(instant: ContactInstant, params: ContactParams, state: int = 0
          ) -> tuple[int, ContactBatch]:
    """One patch's ``n`` consecutive samples, in order, from ``state``: the state after
    the last one and every sample's :class:`ContactBatch` row."""
    n = len(instant)
    fz = instant.force_N[:, 2].tolist()
    ratio = instant.tangential_ratio.tolist()
    known = (instant.valid_taxels > 0).tolist()
    defined = instant.cop_defined.tolist()
    out = np.zeros((n, 2), dtype=bool)
    onset, release, mu, near = params.onset_N, params.release_N, params.friction, \
        params.near_slip_ratio
    contact, slipping = bool(state & IN_CONTACT), bool(state & SLIPPING)
    for i in range(n):
        if known[i]:
            contact = fz[i] >= release if contact else fz[i] >= onset
            if defined[i]:
                slipping = ratio[i] >= near if slipping else ratio[i] >= mu
        slipping = slipping and contact
        out[i] = contact, slipping
    now, slip = out[:, 0], out[:, 1]
    was = np.concatenate([[bool(state & IN_CONTACT)], now[:-1]])
    was_slipping = np.concatenate([[bool(state & SLIPPING)], slip[:-1]])
    judged = (instant.valid_taxels > 0) & instant.cop_defined
    batch = ContactBatch(instant, now, now & ~was, was & ~now, slip, slip & ~was_slipping,
                         now & judged & instant.near_slip)
    return int(now[-1]) * IN_CONTACT + int(slip[-1]) * SLIPPING if n else state, batch


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
            "taxels_in_contact": self.taxels_in_contact, "valid_taxels": self.valid_taxels,
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
