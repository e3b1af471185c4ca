"""`skin view --snapshot`: one frame of the live view as plain text, held by golden files.

The input is made here, byte for byte (a .log of force PDOs with fixed timestamps; force
frames with chosen reasons), so the output is exact. ``UPDATE_GOLDEN=1 pytest ...``
rewrites the golden files (then read them: they are what a user sees).
"""

from __future__ import annotations

import os
from pathlib import Path

import can
import numpy as np
import pytest

from canbus.master.dataplane import ForceFrame
from canbus.master.forcenode import ForceNode
from canbus.tools.recorder import CandumpLogWriter
from decoder.reasons import Reason
from skin.cli import main
from skin.commands.view.layout import Layout
from skin.commands.view.term import SkinView

GOLDEN = Path(__file__).resolve().parents[1] / "files" / "view"
T0 = 1000.0


def _check(name: str, text: str) -> None:
    path = GOLDEN / name
    if os.environ.get("UPDATE_GOLDEN"):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    assert text == path.read_text(encoding="utf-8")  # exact: text from integer mN
    assert "\x1b" not in text  # plain text: no escape codes


def _recording(path: Path) -> None:
    """1 s at 100 Hz after the force nodes' boot-up: patch 1 pressed with shear; patch 2
    with an invalid taxel and, every 10th cycle (7, 17, ...), TPDO 3 lost; patch 3 silent
    after 0.5 s. A reader names each force node by its heartbeat and its first whole set of
    default PDOs, that sample included (no config is given)."""
    nodes = {1: ForceNode(65, 1), 2: ForceNode(66, 2), 3: ForceNode(67, 3)}
    one = np.zeros((9, 3))
    one[:, 2] = 0.02
    one[4] = (0.6, 0.3, 3.2)
    one[5] = (-1.5, 0.0, 1.1)
    one[0] = (0.0, -0.4, 6.3)  # beyond the 5 N scale
    two = np.zeros((9, 3))
    two[1] = (0.2, 0.2, 0.8)
    valid_two = np.ones(9, dtype=bool)
    valid_two[8] = False
    with path.open("w", encoding="utf-8") as handle:
        writer = CandumpLogWriter(handle)
        for node in (65, 66, 67):  # the force nodes boot (a reader knows them from then on)
            writer.on_message_received(can.Message(
                arbitration_id=0x700 + node, data=b"\0", timestamp=T0,
                is_extended_id=False))
        for k in range(100):
            t = T0 + 0.01 * k
            frames = [(0x80, bytes([k % 240 + 1]))]
            frames += nodes[1].frames(one, np.ones(9, bool), True)
            lost = nodes[2].frames(two, valid_two, True)
            if k % 10 == 7:
                del lost[2]
            frames += lost
            if k < 50:
                frames += nodes[3].frames(np.zeros((9, 3)), np.ones(9, bool), True)
            for n, (cob, data) in enumerate(frames):
                writer.on_message_received(can.Message(
                    arbitration_id=cob, data=data, timestamp=t + 1e-4 * n,
                    is_extended_id=False))
        writer.stop()


def test_the_snapshot_of_a_recording_is_exactly_the_golden_one(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "golden.log"
    _recording(path)
    # just after patch 2's first PDO of cycle 98: its partial sample of cycle 97 is shown
    code = main(["view", str(path), "--snapshot", "--at", "0.98095",
                 "--layout", "1=0,0", "2=0.05,0", "3=0,0.05", "4=0.05,0.05"])
    assert code == 0
    _check("snapshot.txt", capsys.readouterr().out)


def test_the_view_s_text_of_decoded_frames_names_every_reason() -> None:
    view = SkinView(Layout.row([1, 2]), 5.0, title="skin view (decoded)")
    force = np.zeros((9, 3))
    force[4] = (0.05, 0.02, 2.5)
    valid = np.ones(9, dtype=bool)
    reason = np.zeros(9, dtype=np.uint8)
    for taxel, why in ((0, Reason.OPEN), (2, Reason.FAULTY), (6, Reason.OUT_OF_RANGE),
                       (8, Reason.SATURATED)):
        valid[taxel], reason[taxel] = False, why
    for cycle in range(1, 11):
        view.update(ForceFrame(1, 65, cycle, cycle, T0 + 0.01 * cycle, force, valid, reason,
                               True, False))
    missing = np.full(9, Reason.MISSING, dtype=np.uint8)
    view.update(ForceFrame(2, 66, 1, 1, T0, np.zeros((9, 3)), np.zeros(9, bool), missing,
                           False, False))
    _check("reasons.txt", view.text(T0 + 0.105, "t 0.105 s"))
