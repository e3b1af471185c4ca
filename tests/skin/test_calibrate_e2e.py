"""The calibration loop end to end, in separate processes on udp_multicast, on a patch unlike
the model (the ``calibration`` scene: 1.5x the crosstalk, readings 3 % high):

``skin sim run calibration --truth`` recorded by ``skin sniff --record`` with ``skin run``
configuring and running the patch (twice) -> ``skin dataset from-recording`` ->
``skin calibrate`` -> ``skin decode`` of the second recording, the listen-only host offline,
with the calibrated model: its floored error is at most 1.2x the oracle's, while the
uncalibrated analytic decoder is at least 5x worse. (tests/support/rigs/calibration.py)
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from canbus.offline.dataset import dataset_from_recording
from decoder.registry import load_decoder
from decoder.tare import nominal_r0, normalise
from skin.constants import DEFAULT_CONSTANTS
from skin.reference import read_reference
from tests.support.rigs.calibration import loop, record

SAMPLES = 350  # answered SYNCs per recording: the run lasts until the patch answered them


@pytest.mark.slow
def test_a_recorded_patch_calibrated_end_to_end(tmp_path: Path,
                                                udp_bus: tuple[str, int]) -> None:
    record(tmp_path, classic=True, samples=SAMPLES, group=udp_bus[0], port=udp_bus[1])
    for run in (1, 2):  # the simulator was stopped by SIGTERM: its truth is whole
        truth = read_reference(tmp_path / f"truth{run}.csv")
        assert truth.rows == 9 * len(truth.sync) and len(truth.sync) >= SAMPLES
    cwd = os.getcwd()
    try:
        figures = loop(tmp_path, classic=True)
    finally:
        os.chdir(cwd)
    assert figures.compared_samples > 100
    assert figures.calibrated_pct <= 1.2 * figures.oracle_pct, figures
    assert figures.analytic_pct >= 5 * max(figures.calibrated_pct, figures.oracle_pct), figures
    for key in ("heldout_floored_pct", "decoder", "hidden"):
        assert key in figures.report
    assert figures.report["tare"]["samples"] >= 10
    # the listen-only host feeds the model exactly the frame it was fitted in (to the last
    # bits a decode's batch size may change)
    made = dataset_from_recording(tmp_path / "run2.log", tmp_path / "truth2.csv")
    report = figures.report
    model = load_decoder(tmp_path / "m.msgpack")
    x = normalise(made.dataset.resistance_ohm[:, 0], np.array(report["tare"]["rest_ohm"]),
                  nominal_r0(DEFAULT_CONSTANTS, 3))
    want = model.decode(x)
    with np.load(tmp_path / "calibrated.npz") as z:
        by_cycle = {int(c): k for k, c in enumerate(z["cycle"]) if z["patch"][k] == 1}
        rows = [by_cycle[int(c)] for c in made.cycles]
        np.testing.assert_allclose(z["force_N"][rows], want.force_N, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(z["valid"][rows], want.valid)

