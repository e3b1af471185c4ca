"""Calibration from arrays: the tare at rest, the frame a calibrated model reads (the host's),
contiguous folds, the choice of decoder and its report."""

from __future__ import annotations

import math

import numpy as np
import pytest

from canbus.master.baseline import Baseline
from decoder.calibration import (
    Candidate,
    calibrate,
    choose,
    default_candidates,
    folds_of,
    make_decoder,
    parse_candidate,
    report,
)
from decoder.metrics import evaluate
from decoder.registry import create_decoder
from decoder.tare import MIN_REST_SAMPLES, as_reported, nominal_r0, normalise, tare_at_rest
from sim import generate_dataset, load_scene
from skin.constants import DEFAULT_CONSTANTS
from skin.errors import ConfigError, DecodeError

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels


@pytest.fixture(scope="module")
def data() -> tuple[np.ndarray, np.ndarray]:
    ds = generate_dataset(load_scene("calibration"), 300, 11)
    return ds.resistance_ohm[:, 0], ds.force_N[:, 0]


def test_the_tare_is_the_mean_rest_reading_as_a_patch_holds_it(
        data: tuple[np.ndarray, np.ndarray]) -> None:
    r, f = data
    rest = np.all(np.linalg.norm(f, axis=2) <= 0.01, axis=1)  # every taxel at most 0.01 N
    assert rest.sum() > np.all(f == 0, axis=(1, 2)).sum()  # some barely touched
    tare = tare_at_rest(r, f)
    assert tare is not None and tare.samples == rest.sum() >= MIN_REST_SAMPLES
    np.testing.assert_array_equal(tare.rest_ohm, as_reported(r[rest].mean(axis=0)))
    np.testing.assert_allclose(tare.rest_ohm / DEFAULT_CONSTANTS.nominal_resistance_ohm, 1.03,
                               rtol=2e-4)  # the scene reads 3 % high
    few = np.flatnonzero(rest)[MIN_REST_SAMPLES - 1:]
    assert tare_at_rest(np.delete(r, few, 0), np.delete(f, few, 0)) is None
    assert tare_at_rest(r, f + 0.02) is None  # nothing is at rest under 0.01 N
    assert tare_at_rest(r, f + 0.02, rest_N=0.05) is not None


def test_the_frame_is_what_the_host_feeds_a_decoder(data: tuple[np.ndarray, np.ndarray]
                                                    ) -> None:
    r, f = data
    tare = tare_at_rest(r, f)
    assert tare is not None
    r0 = nominal_r0(DEFAULT_CONSTANTS, 3)
    # the host: baseline = the R0 the patch reports (whole mOhm), scale = r0 / baseline
    host = Baseline(r0, tare.rest_ohm, loaded_N=0.05)
    np.testing.assert_array_equal(r * host.scale, normalise(r, tare.rest_ohm, r0))
    same = Baseline(r0, as_reported(r0), loaded_N=0.05)  # a patch that reports the nominal R0
    np.testing.assert_array_equal(r * same.scale, normalise(r, as_reported(r0), r0))


def test_folds_are_contiguous_and_cover_everything() -> None:
    folds = folds_of(23, 5)
    assert [len(f) for f in folds] == [5, 5, 5, 4, 4]
    np.testing.assert_array_equal(np.concatenate(folds), np.arange(23))
    for fold in folds:
        assert np.all(np.diff(fold) == 1)
    with pytest.raises(ConfigError, match="--folds"):
        folds_of(3, 5)


def _candidate(name: str, pct: float, us: float, flagged: float = 0.0) -> Candidate:
    nan9 = np.full(9, math.nan)
    return Candidate(name, None, pct, pct, 0.0, np.zeros(3), nan9, np.zeros(9, np.int64), nan9,
                     np.array([pct]), flagged, 0.0, latency_us=us)


def test_choice_by_heldout_error_ties_by_speed_refusals_excluded() -> None:
    assert choose([_candidate("a", 3.0, 10), _candidate("b", 2.0, 50)]).name == "b"
    assert choose([_candidate("a", 2.03, 10), _candidate("b", 2.0, 50)]).name == "a"  # tie
    assert choose([_candidate("a", 2.1, 10), _candidate("b", 2.0, 50)]).name == "b"
    flagged = [_candidate("a", 1.0, 10, flagged=0.02), _candidate("b", 2.0, 50)]
    assert choose(flagged).name == "b" and not flagged[0].eligible
    assert "refused 2.00 %" in flagged[0].why
    with pytest.raises(DecodeError, match="no candidate decoder qualifies"):
        choose([_candidate("a", 1.0, 10, flagged=0.5)])


def test_calibrate_chooses_refits_and_reports(data: tuple[np.ndarray, np.ndarray]) -> None:
    r, f = data
    tare = tare_at_rest(r, f)
    assert tare is not None
    r0 = nominal_r0(DEFAULT_CONSTANTS, 3)
    x = normalise(r, tare.rest_ohm, r0)
    stages: list[tuple[str, int, int]] = []
    cal = calibrate(x, f, DEFAULT_CONSTANTS, names=["analytic", "deconv"], folds=4,
                    stage=lambda *s: stages.append(s))
    assert cal.best.name == "deconv" and cal.decoder.name == "deconv"
    assert stages[-1] == ("done", 9, 9) and [s[1] for s in stages] == sorted(s[1] for s in stages)
    # the held-out figure is the out-of-fold forces' floored AveRelErr
    pred = np.zeros_like(f)
    valid = np.zeros(f.shape[:2], dtype=bool)
    for test in folds_of(len(x), 4):
        train = np.setdiff1d(np.arange(len(x)), test)
        out = create_decoder("deconv").fit(x[train], f[train]).decode(x[test])
        pred[test], valid[test] = out.force_N, out.valid
    want = evaluate(f, pred, valid, mode="xyz").ave_rel_err_floored_pct
    assert cal.best.heldout_floored_pct == pytest.approx(want, rel=1e-12)
    analytic = next(c for c in cal.candidates if c.name == "analytic")
    assert analytic.heldout_floored_pct > 2 * cal.best.heldout_floored_pct  # 1.5x crosstalk
    found = report(cal, tare.rest_ohm, tare.samples, 0.01, tare.noise_ohm)
    assert found["decoder"] == "deconv" and found["hidden"] is None
    assert set(found["rmse_axis_N"]) == {"Fx", "Fy", "Fz"}
    assert found["per_taxel_floored_pct"].shape == (9,)
    assert found["speed"]["latency_us"] > 0 and found["domain"]["samples"] == len(x)
    assert [c["decoder"] for c in found["candidates"]] == ["analytic", "deconv"]


def test_the_default_candidates_learn_and_unknown_names_fail_first(
        data: tuple[np.ndarray, np.ndarray]) -> None:
    names = default_candidates()
    assert names[0] == "analytic" and {"deconv", "lm-mlp", "hybrid"} <= set(names)
    assert "eq9" not in names
    r, f = data
    with pytest.raises(ConfigError, match="unknown decoder 'nope'"):
        calibrate(r, f, DEFAULT_CONSTANTS, names=["deconv", "nope"])


def test_a_candidate_may_name_its_hidden_nodes() -> None:
    assert parse_candidate("lm-mlp:8") == ("lm-mlp", 8)
    assert parse_candidate("hybrid:auto") == ("hybrid", "auto")
    assert parse_candidate("deconv") == ("deconv", None)
    lm = make_decoder("lm-mlp:7", DEFAULT_CONSTANTS, hidden=12)
    assert getattr(lm, "hidden", None) == 7  # the spec's own, over --hidden
    assert getattr(make_decoder("lm-mlp", DEFAULT_CONSTANTS, hidden=12), "hidden", None) == 12
    for spec, message in (("deconv:4", "has no hidden nodes"), ("lm-mlp:0", "1..1000 or auto"),
                          ("lm-mlp:x", "1..1000 or auto"), ("nope:3", "unknown decoder")):
        with pytest.raises(ConfigError, match=message):
            parse_candidate(spec)
