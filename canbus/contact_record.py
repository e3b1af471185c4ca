"""The contact summary on the wire: a force node's objects 0x2008 (contact) and 0x2009
(the thresholds it is judged by), their units, and the state byte.

0x2008, RECORD, every sub-index PDO-mappable, read-only:

| sub | name | type | unit |
|---|---|---|---|
| 1..3 | net force Fx, Fy, Fz | INTEGER16 | 10 mN |
| 4..6 | torque Tx, Ty, Tz about the patch centre | INTEGER16 | 0.1 mN·m |
| 7, 8 | centre of pressure x, y, patch frame | INTEGER16 | 0.01 mm |
| 9, 10 | centre of pressure x, y, placed frame | INTEGER16 | 0.1 mm |
| 11 | state | UNSIGNED8 | bits below |
| 12 | taxels in contact | UNSIGNED8 | count |
| 13 | contact taxels | UNSIGNED16 | bit k = taxel k |
| 14 | slipping taxels | UNSIGNED16 | bit k = taxel k |
| 15 | tangential ratio of the net force | UNSIGNED16 | 0.001 |

An INTEGER16 value is 0x8000 (-32768) and the ratio 0xFFFF when it has no value: the CoP
while no taxel is in contact, everything but the state while no taxel is valid, and any
value that does not fit its type (never clipped, never NaN). State bits: 0 in contact,
1 contact onset (this sample), 2 release (this sample), 3 near slip, 4 slipping, 5 slip
onset, 6 partial (some taxel invalid: the figures rest on the others), 7 unknown (no valid
taxel: the state bits 0 and 4 are the ones held from before).

0x2009, RECORD of UNSIGNED32, read-only, scaled integers (every CANopen stack reads them
alike, as it does not a REAL32 default): 1 taxel contact threshold (mN), 2 onset (mN),
3 release (mN), 4 friction coefficient (x1000), 5 near-slip margin (x1000).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skin.contact import ContactInstant, ContactParams
from skin.contact_state import (
    CONTACT_BIT,
    NEAR_SLIP,
    ONSET,
    PARTIAL,
    RELEASE,
    SLIP_BIT,
    SLIP_ONSET,
    UNKNOWN,
    ContactBatch,
)

CONTACT, CONTACT_PARAMS = 0x2008, 0x2009
SUBS = 15
IN_CONTACT, SLIPPING = CONTACT_BIT, SLIP_BIT
__all__ = ["IN_CONTACT", "NEAR_SLIP", "ONSET", "PARTIAL", "RELEASE", "SLIPPING", "SLIP_ONSET",
           "UNKNOWN", "BusContact", "columns", "decode", "describe", "encode", "no_summary",
           "param_values",
           "state_text"]
STATE_NAMES = ("contact", "onset", "release", "near-slip", "slipping", "slip-onset",
               "partial", "unknown")
NO_VALUE = -0x8000
NO_RATIO = 0xFFFF
FORCE_SUBS, TORQUE_SUBS, COP_SUBS, PLACED_SUBS = (1, 2, 3), (4, 5, 6), (7, 8), (9, 10)
STATE, COUNT, CONTACT_MASK, SLIP_MASK, RATIO = 11, 12, 13, 14, 15
SCALE = {**dict.fromkeys(FORCE_SUBS, 0.01), **dict.fromkeys(TORQUE_SUBS, 1e-4),
         **dict.fromkeys(COP_SUBS, 1e-5), **dict.fromkeys(PLACED_SUBS, 1e-4), RATIO: 1e-3}
"""SI units per count of each scaled sub-index (N, N·m, m, m, 1)."""
COUNTS_PER_UNIT = {sub: float(round(1.0 / scale)) for sub, scale in SCALE.items()}
"""Counts per SI unit (exact integers): a value's count is ``rint(value ·
COUNTS_PER_UNIT[sub])``."""
UNIT = {**dict.fromkeys(FORCE_SUBS, "N"), **dict.fromkeys(TORQUE_SUBS, "N·m"),
        **dict.fromkeys(COP_SUBS, "m"), **dict.fromkeys(PLACED_SUBS, "m"), RATIO: ""}
NAMES = {1: "Fx", 2: "Fy", 3: "Fz", 4: "Tx", 5: "Ty", 6: "Tz", 7: "CoPx", 8: "CoPy",
         9: "CoPX", 10: "CoPY", 11: "state", 12: "taxels", 13: "contact", 14: "slip",
         15: "ratio"}
DEFAULT_TPDO = (3, 7, 8, STATE, COUNT)
"""The default contact TPDO (TPDO 8, 8 bytes): net Fz, CoP x, CoP y, state, count."""
PARAM_SUBS = ("taxel_contact_N", "onset_N", "release_N", "friction", "near_slip_margin")
PARAM_SCALE = 1e-3
"""Every 0x2009 sub-index counts thousandths: mN for the thresholds, 0.001 for the rest."""
PUBLISHED = (8, 7, 3)
"""The scaled sub-indices among :data:`DEFAULT_TPDO`, in the order of the rows of
:attr:`skin.contact_sums.SumsKernel.published` (CoP y, CoP x, net Fz)."""
NO_COUNT = 0x7FFF
"""The largest INTEGER16 count a value may round to (beyond it: no value, never clipped)."""


def encode(batch: ContactBatch, subs: Sequence[int]) -> NDArray[np.int64]:
    """``(n, len(subs))``: the values of sub-indices ``subs`` of 0x2008 for every sample, as
    the objects hold them (only those asked for are computed)."""
    out = np.empty((len(batch), len(subs)), dtype=np.int64)
    for j, sub in enumerate(subs):
        out[:, j] = _column(batch, sub)
    return out


def columns(batch: ContactBatch, subs: Sequence[int]) -> NDArray[np.int64]:
    """``(n, 15)``: sub-index 1..15 of 0x2008 in column 0..14, those of ``subs`` filled in
    (the others 0)."""
    out = np.zeros((len(batch), SUBS), dtype=np.int64)
    for sub in dict.fromkeys(subs):
        out[:, sub - 1] = _column(batch, sub)
    return out


def _column(batch: ContactBatch, sub: int) -> NDArray[np.int64]:
    instant = batch.instant
    if not 1 <= sub <= SUBS:
        raise ValueError(f"0x{CONTACT:04X} has no sub-index {sub}")
    if sub <= 10:
        values, has = _source(instant, sub)
        with np.errstate(over="ignore", invalid="ignore"):  # such values have no value
            counts = np.rint(values * COUNTS_PER_UNIT[sub])
        has = has & (np.abs(counts) <= NO_COUNT)  # False for NaN and inf too
        return np.where(has, counts, NO_VALUE).astype(np.int64)
    if sub == STATE:
        return batch.state_byte.astype(np.int64)
    if sub == COUNT:
        return instant.taxels_in_contact
    if sub == CONTACT_MASK:
        return _mask(instant.contact_taxels)
    if sub == SLIP_MASK:
        return _mask(instant.taxel_slip)
    with np.errstate(over="ignore", invalid="ignore"):
        ratio = np.rint(instant.tangential_ratio * COUNTS_PER_UNIT[RATIO])
    return np.where(instant.cop_defined & (ratio < NO_RATIO), ratio, NO_RATIO).astype(np.int64)


def _source(instant: ContactInstant, sub: int) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """A scaled sub-index's SI values and where it has a value."""
    if sub in FORCE_SUBS:
        return instant.force_N[:, sub - 1], instant.known
    if sub in TORQUE_SUBS:
        return instant.torque_Nm[:, sub - 4], instant.known
    if sub in COP_SUBS:
        return instant.cop_m[:, sub - 7], instant.cop_defined
    return instant.cop_placed_m[:, sub - 9], instant.cop_defined


def no_summary(subs: Sequence[int], n: int) -> NDArray[np.int64]:
    """``(n, len(subs))``: what sub-indices ``subs`` hold without a summary (no valid taxel,
    or a node that computes none): no value, state ``unknown``, no taxel."""
    row = [NO_VALUE if s <= 10 else UNKNOWN if s == STATE else NO_RATIO if s == RATIO else 0
           for s in subs]
    return np.tile(np.array(row, dtype=np.int64), (n, 1))


def _mask(taxels: NDArray[np.bool_]) -> NDArray[np.int64]:
    bits: NDArray[np.int64] = (taxels.astype(np.int64) << np.arange(taxels.shape[1])).sum(axis=1)
    return bits


def param_values(params: ContactParams) -> tuple[int, ...]:
    """0x2009 sub-index 1..5, in thousandths (:data:`PARAM_SCALE`)."""
    return tuple(round(float(getattr(params, name)) / PARAM_SCALE) for name in PARAM_SUBS)


@dataclass(frozen=True)
class BusContact:
    """A contact summary as read off the bus (the sub-indices a master mapped; None where
    not mapped or without a value), in SI units."""

    force_N: tuple[float | None, float | None, float | None]
    torque_Nm: tuple[float | None, float | None, float | None]
    cop_m: tuple[float, float] | None
    cop_placed_m: tuple[float, float] | None
    state: int | None
    taxels_in_contact: int | None
    contact_taxels: int | None  # bit k = taxel k
    slip_taxels: int | None
    tangential_ratio: float | None

    def flag(self, bit: int) -> bool | None:
        return None if self.state is None else bool(self.state & bit)

    @property
    def in_contact(self) -> bool | None:
        return self.flag(IN_CONTACT)

    @property
    def slipping(self) -> bool | None:
        return self.flag(SLIPPING)

    @property
    def near_slip(self) -> bool | None:
        return self.flag(NEAR_SLIP)


def decode(values: dict[int, int]) -> BusContact:
    """The raw values of the mapped sub-indices of 0x2008 (sub -> value) in SI units."""

    def scaled(sub: int) -> float | None:
        raw = values.get(sub)
        if raw is None or raw == NO_VALUE:
            return None
        return raw * SCALE[sub]

    def pair(a: int, b: int) -> tuple[float, float] | None:
        x, y = scaled(a), scaled(b)
        return None if x is None or y is None else (x, y)

    ratio = values.get(RATIO)
    return BusContact(
        (scaled(1), scaled(2), scaled(3)), (scaled(4), scaled(5), scaled(6)), pair(7, 8),
        pair(9, 10), values.get(STATE), values.get(COUNT), values.get(CONTACT_MASK),
        values.get(SLIP_MASK),
        None if ratio is None or ratio == NO_RATIO else ratio * SCALE[RATIO])


def describe(sub: int, raw: int) -> tuple[str, float | None, str, str]:
    """Sub-index ``sub``'s raw value in words: (short name, SI value or None, unit, text),
    e.g. ``("Fz", 3.0, "N", "Fz=+3.00 N")`` (what the sniffer shows)."""
    name = NAMES[sub]
    if sub == STATE:
        return name, float(raw), "", f"{name}={state_text(raw)}"
    if sub == COUNT:
        return name, float(raw), "", f"{name}={raw}"
    if sub in (CONTACT_MASK, SLIP_MASK):
        taxels = ",".join(str(k) for k in range(9) if raw >> k & 1) or "none"
        return name, float(raw), "", f"{name}={taxels}"
    unit = UNIT[sub]
    if raw == (NO_RATIO if sub == RATIO else NO_VALUE):
        return name, None, unit, f"{name}=none"
    si = raw * SCALE[sub]
    shown = {"m": f"{1000 * si:+.2f} mm", "N": f"{si:+.2f} N", "N·m": f"{si:+.4f} N·m"}
    return name, si, unit, f"{name}={shown.get(unit, f'{si:.3f}')}"


def state_text(state: int) -> str:
    """``contact,near-slip`` (``free`` with no bit set)."""
    names = [name for k, name in enumerate(STATE_NAMES) if state >> k & 1]
    return ",".join(names) if names else "free"
