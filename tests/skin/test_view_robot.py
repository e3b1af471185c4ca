"""`skin view` shows the contacts on the robot's links of patches placed on links (a host's
frames, as ``--decode --config`` makes them), and nothing more for a flat skin."""

from __future__ import annotations

import numpy as np

from canbus.master.contact import PatchContact, summarize_batch
from canbus.master.dataplane import ForceFrame
from skin.commands.view.layout import Layout
from skin.commands.view.term import SkinView
from skin.placement import PatchPlacement, Pose

T0 = 100.0
PALM = {3: PatchPlacement("palm", Pose((-0.0225, 0.0, 0.01))),
        4: PatchPlacement("palm", Pose((0.0225, 0.0, 0.01)))}


def _frame(node: int, taxel: int, placement: PatchPlacement | None) -> ForceFrame:
    force = np.zeros((9, 3))
    force[taxel, 2] = 2.0
    valid = np.ones(9, dtype=bool)
    batch = summarize_batch([PatchContact(placement=placement)], force[None], valid[None])
    frame = ForceFrame(node, node + 64, 1, 1, T0, force, valid, np.zeros(9, np.uint8), True,
                       False, batch.row(0))
    if placement is None:
        return frame
    return ForceFrame(*(getattr(frame, f) for f in (
        "patch", "force_node", "cycle", "sync_counter", "timestamp", "force_N", "valid",
        "reason", "complete", "published", "contact")), placement)


def test_patches_on_a_link_show_one_contact_across_their_border() -> None:
    view = SkinView(Layout.row([3, 4]), 5.0)
    view.update(_frame(3, 5, PALM[3]))
    view.update(_frame(4, 3, PALM[4]))
    text = view.text(T0 + 0.005)
    assert "on the robot" in text
    assert "palm (patches 3+4)  point (0.0, 0.0, 10.0)  force (+0.00, +0.00, -4.00)" in text


def test_a_flat_skin_shows_no_robot() -> None:
    view = SkinView(Layout.row([3, 4]), 5.0)
    view.update(_frame(3, 5, None))
    view.update(_frame(4, 3, None))
    assert "on the robot" not in view.text(T0 + 0.005)
