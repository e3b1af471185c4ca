"""What ``skin view`` shows of a patch's contact summary, from either source.

A decoded sample (the host's ``ForceFrame``, ``--decode``) carries the whole summary
(``ForceFrame.contact``). A sample read off the bus (``ForceSample``) carries what its
force node's contact PDO maps (``ForceSample.contact``; by default net Fz, the CoP, the
state and the taxels in contact): the net shear, unless a master mapped 0x2008 sub-index
1 and 2, is then the sum of the shear of the taxels the contact mask names when mapped,
else of the valid taxels whose Fz is above the default contact threshold (0.12 N; the
forces are in the same sample).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from skin.contact import ContactParams

TAXEL_CONTACT_N = ContactParams().taxel_contact_N

CONTACT_BIT, NEAR_SLIP_BIT, SLIP_BIT = 0x01, 0x08, 0x10


@dataclass(frozen=True)
class ViewContact:
    """One patch-sample's contact as the view draws it."""

    fz_N: float | None  # net normal force over the taxels in contact
    shear_N: tuple[float, float]  # net (Fx, Fy)
    cop_m: tuple[float, float] | None  # patch frame; None: not defined (no taxel in contact)
    in_contact: bool
    near_slip: bool
    slipping: bool

    @property
    def mark(self) -> str:
        """``SLIP``, ``near`` (near slip) or nothing."""
        return "SLIP" if self.slipping else "near" if self.near_slip else ""


def view_contact(sample: Any) -> ViewContact | None:
    """The contact of a ``ForceFrame`` or ``ForceSample``; None when it carries none."""
    contact = getattr(sample, "contact", None)
    if contact is None:
        return None
    if hasattr(contact, "cop_defined"):  # the host's ContactSummary
        fx, fy, fz = (float(v) for v in contact.force_N)
        x, y = (float(v) for v in contact.cop_m)
        return ViewContact(fz, (fx, fy), (x, y) if contact.cop_defined else None,
                           contact.in_contact, contact.near_slip, contact.slipping)
    state = contact.state or 0
    fx, fy, fz = contact.force_N
    if fx is None or fy is None:
        mask = contact.contact_taxels
        taxels = [k for k in range(9) if bool(sample.valid[k]) and (
            float(sample.force_N[k][2]) > TAXEL_CONTACT_N if mask is None else mask >> k & 1)]
        fx = sum(float(sample.force_N[k][0]) for k in taxels)
        fy = sum(float(sample.force_N[k][1]) for k in taxels)
    return ViewContact(fz, (fx, fy), contact.cop_m, bool(state & CONTACT_BIT),
                       bool(state & NEAR_SLIP_BIT), bool(state & SLIP_BIT))


def contact_lines(contact: ViewContact | None, arrow: Callable[[float, float], str]
                  ) -> tuple[str, str]:
    """Two lines of at most 22 characters: the net force and shear (``arrow`` draws its
    direction), and the CoP in mm (or whether the patch is in contact)."""
    if contact is None:
        return "", ""
    fz = "  -  " if contact.fz_N is None else f"{contact.fz_N:5.2f}"
    fx, fy = contact.shear_N
    glyph = arrow(fx, fy)
    first = f"ΣF {fz} N {glyph}{math.hypot(fx, fy):5.2f} N"
    if contact.cop_m is None:
        where = "in contact" if contact.in_contact else "no contact"
    else:
        x, y = (1000.0 * v for v in contact.cop_m)
        where = f"CoP{x:+6.1f}{y:+6.1f}"
    return first, where


def nearest_taxel(cop_m: tuple[float, float], pitch_m: float) -> int:
    """The taxel whose centre is nearest the CoP (patch frame)."""
    column = min(max(round(cop_m[0] / pitch_m) + 1, 0), 2)
    row = min(max(round(cop_m[1] / pitch_m) + 1, 0), 2)
    return 3 * row + column
