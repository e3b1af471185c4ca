"""The truth of contact: the stick-slip load and the summary of the true loads."""

from __future__ import annotations

import re
from typing import Any

import numpy as np
import pytest

from sim import Simulator, load_scene, scene_from_dict
from sim.contact_truth import true_contact
from sim.stickslip import StickSlip, StickSlipParams
from skin.contact import ContactParams, taxel_xy
from skin.errors import ConfigError

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels

PITCH = 0.015


def test_stick_slip_ramps_past_the_friction_limit_and_slips_from_there() -> None:
    p = StickSlipParams()
    load = StickSlip(p, 2, 100.0, PITCH, seed=3, name="loads[0]")
    force = load.forces(0, 300)
    slip = load.slipping(0, 300)
    fz = force[..., 2].sum(axis=2)
    ratio = np.hypot(force[..., 0].sum(axis=2), force[..., 1].sum(axis=2)) / np.where(
        fz > 0, fz, 1.0)
    for patch in range(2):
        onsets = np.flatnonzero(np.diff(slip[:, patch].astype(int), prepend=0) == 1)
        assert onsets.tolist() == [30, 130, 230]  # ramp_s = 0.3 s into each 1 s cycle
        for k in onsets:  # the first step at the limit: just below it one step earlier
            assert ratio[k, patch] == pytest.approx(p.friction, rel=1e-9)
            assert ratio[k - 1, patch] < p.friction
        assert ratio[slip[:, patch], patch].min() >= p.friction * (1 - 1e-9)
        assert (ratio[~slip[:, patch], patch] < p.friction).all()
        lifted = np.array([(k % 100) >= 75 for k in range(300)])
        assert not fz[lifted, patch].any() and (fz[~lifted, patch] > 1.0).all()
    # each cycle draws its own centre and direction, the same for the same seed
    assert not np.allclose(force[10], force[110])
    np.testing.assert_array_equal(force, StickSlip(p, 2, 100.0, PITCH, 3, "loads[0]")
                                  .forces(0, 300))
    # the object slides in its slip phase: the true CoP moves only then
    cop = (force[..., 2] @ taxel_xy(PITCH)) / np.where(fz > 0, fz, 1.0)[..., None]
    moved = np.hypot(*np.diff(cop[:, 0], axis=0).T) > 1e-9
    assert moved[30:44].all() and not moved[1:29].any() and not moved[46:74].any()


@pytest.mark.parametrize(("change", "field"), [
    ({"friction": 0.0}, "loads[0].friction"), ({"ramp_s": -1.0}, "loads[0].ramp_s"),
    ({"period_s": 0.5}, "loads[0].period_s"), ({"lift_s": -0.1}, "loads[0].lift_s")])
def test_stick_slip_parameters_are_checked(change: dict[str, Any], field: str) -> None:
    scene: dict[str, Any] = {"scene": {"name": "s", "mode": "xyz"}, "patches": [{"node_id": 1}],
                             "loads": [{"kind": "stick_slip", **change}]}
    with pytest.raises(ConfigError, match="^" + re.escape(field)):
        scene_from_dict(scene)


def test_the_truth_of_the_shipped_stick_slip_scene() -> None:
    scene = load_scene("stick-slip")
    frame = Simulator(scene, seed=1).run(200)
    (truth,) = true_contact(frame, scene)
    force = frame.force_N[:, 0]
    np.testing.assert_allclose(truth.batch.instant.force_N, force.sum(axis=1), atol=1e-12)
    assert truth.slip_onsets.tolist() == [30, 130]
    assert truth.batch.onset.sum() == 2 and truth.batch.release.sum() == 2
    assert not (truth.slip & ~truth.batch.in_contact).any()


def test_the_truth_counts_every_loaded_taxel_and_slide_slides_while_it_touches() -> None:
    scene = load_scene("slide")
    frame = Simulator(scene, seed=0).run(400)
    (truth,) = true_contact(frame, scene, ContactParams(taxel_contact_N=5.0))
    loaded = frame.force_N[:, 0, :, 2] > 0
    np.testing.assert_array_equal(truth.batch.instant.contact_taxels, loaded)
    assert (truth.slip == truth.batch.in_contact).all() and truth.slip.any()
    assert not frame.slip[~loaded.any(axis=1), 0].any()
    for name in ("indenter", "grasp"):
        scene = load_scene(name)
        assert not Simulator(scene).run(50).slip.any()
