"""`skin bench robot` on the example robot: every key it promises, and the bar the issue
sets (contact point p95 within 2 mm of the press, net force within 5 % of full scale, every
press across two patches reported as one contact). The figures come from fixed seeds, so
the bar is a property of the product's geometry and decoding, not of the machine."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from canbus.master.channel import ForceFrame
from canbus.master.robot import robot_contacts
from skin.cli import main
from skin.contact import ContactParams, summarize
from skin.contact_state import track
from skin.placement import PatchPlacement, Pose


def test_skin_bench_robot_meets_the_bar(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "robot.json"
    assert main(["bench", "robot", "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    assert set(r["contact_point_err_mm"]) == {"p50", "p95"}
    assert r["contact_point_err_mm"]["p95"] <= 2.0
    assert r["contact_force_err_pct_fs"]["p95"] <= 5.0
    assert r["links"] == ["forearm", "palm"] == r["links_reported"]
    cross = r["cross_patch_presses"]
    assert cross["count"] >= 20 and cross["merged"] == cross["count"]
    assert r["held_samples"] > 2000 and r["missed_samples"] < 0.02 * r["contact_samples"]
    assert "reported as one contact" in capsys.readouterr().out


def _frame(node: int, cycle: int, placement: PatchPlacement, taxel: int) -> ForceFrame:
    force = np.zeros((9, 3))
    force[taxel, 2] = 1.0
    valid = np.ones(9, dtype=bool)
    _, batch = track(summarize(force[None], valid[None]), ContactParams())
    return ForceFrame(node, node + 64, cycle, 0, 0.0, force, valid, np.zeros(9, np.uint8),
                      True, True, batch.row(0), placement)


def test_robot_contacts_give_each_cycles_contacts_on_the_links() -> None:
    left = PatchPlacement("palm", Pose((-0.0225, 0.0, 0.01)))
    right = PatchPlacement("palm", Pose((0.0225, 0.0, 0.01)))
    frames = [_frame(3, 1, left, 5), _frame(4, 1, right, 3),  # across the border: one contact
              _frame(3, 2, left, 3), _frame(4, 2, right, 5)]  # far apart: two
    got = list(robot_contacts(frames))
    assert [cycle for cycle, _ in got] == [1, 2]
    (one,) = got[0][1]
    assert one.patches == (3, 4) and one.link == "palm"
    np.testing.assert_allclose(one.point_m, [0.0, 0.0, 0.01], atol=1e-15)
    np.testing.assert_allclose(one.normal, [0.0, 0.0, 1.0])
    assert [c.patches for c in got[1][1]] == [(3,), (4,)]
    assert one.to_dict()["taxels"] == [[3, 5], [4, 3]]
