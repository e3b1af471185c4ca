"""`skin view` draws each patch's contact: net force and shear, CoP, slip."""

from __future__ import annotations

import numpy as np

from canbus.contact_record import BusContact
from canbus.master.contact import PatchContact, summarize_batch
from canbus.master.dataplane import ForceFrame
from canbus.tools.forcereader import ForceSample
from skin.commands.view.contact import nearest_taxel, view_contact
from skin.commands.view.layout import Layout
from skin.commands.view.plot import moment_picture
from skin.commands.view.term import SkinView
from skin.contact import ContactParams

T0 = 100.0


def _frames(force: np.ndarray, cycles: int = 3) -> list[ForceFrame]:
    judge = PatchContact(params=ContactParams(friction=0.5))
    valid = np.ones(9, dtype=bool)
    out = []
    for cycle in range(1, cycles + 1):
        batch = summarize_batch([judge], force[None], valid[None])
        out.append(ForceFrame(1, 65, cycle, cycle, T0 + 0.01 * cycle, force, valid,
                              np.zeros(9, np.uint8), True, False, batch.row(0)))
    return out


def test_a_decoded_sample_shows_its_net_force_cop_and_slip() -> None:
    force = np.zeros((9, 3))
    force[5] = (1.2, 0.0, 2.0)  # ratio 0.6 >= 0.5: slipping
    force[2] = (1.2, 0.0, 2.0)
    view = SkinView(Layout.row([1]), 5.0)
    for frame in _frames(force):
        view.update(frame)
    text = view.text(T0 + 0.035)
    assert "ΣF  4.00 N ⇒ 2.40 N" in text
    assert "CoP +15.0  -7.5   SLIP" in text
    row = [line for line in text.splitlines() if "│" in line and "2.0" in line]
    assert row[0].count("◆") == 1  # nearest the CoP (15 mm, -7.5 mm): taxel 5 or 2
    contact = view_contact(view.tracker.status(T0 + 0.035)[1].last)
    assert contact is not None and contact.slipping and contact.mark == "SLIP"
    assert nearest_taxel((0.015, -0.0074), 0.015) == 5
    assert nearest_taxel((-0.03, 0.03), 0.015) == 6  # beyond the patch: its edge taxel


def test_a_sample_off_the_bus_shows_what_the_contact_pdo_carries() -> None:
    force = np.zeros((9, 3))
    force[4] = (0.3, 0.4, 1.0)
    force[0] = (5.0, 0.0, 0.05)  # below the contact threshold: not summed into the shear
    bus = BusContact((None, None, 1.05), (None,) * 3, (0.0, 0.001), None, 0x09, 1, None,
                     None, None)
    sample = ForceSample(1, 65, T0, force, np.ones(9, bool), np.zeros(9, np.uint8), True, 0,
                         None, bus)
    contact = view_contact(sample)
    assert contact is not None and contact.near_slip and not contact.slipping
    assert contact.shear_N == (0.3, 0.4) and contact.fz_N == 1.05
    view = SkinView(Layout.row([1]), 5.0)
    view.update(sample)
    text = view.text(T0)
    assert "ΣF  1.05 N ↗ 0.50 N" in text and "CoP  +0.0  +1.0   near" in text


def test_no_summary_no_contact_lines_and_the_picture_marks_slip() -> None:
    view = SkinView(Layout.row([1]), 5.0)
    frame = _frames(np.zeros((9, 3)), 1)[0]
    bare = ForceFrame(*(getattr(frame, f) for f in (
        "patch", "force_node", "cycle", "sync_counter", "timestamp", "force_N", "valid",
        "reason", "complete", "published")))
    view.update(bare)
    assert "ΣF" not in view.text(T0 + 0.01).split("taxel 0 bottom left")[1].split(
        "margin")[1]
    force = np.zeros((9, 3))
    force[4] = (2.0, 0.0, 2.0)
    slipping = SkinView(Layout.row([1]), 5.0)
    for f in _frames(force):
        slipping.update(f)
    picture = moment_picture(slipping.state(T0 + 0.035), scale_N=5.0, time_s=0.0)
    labels = [t.get_text() for t in picture.axes.texts]
    assert "SLIP" in labels
