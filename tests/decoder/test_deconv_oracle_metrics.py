"""deconv against the oracle, near-singular crosstalk, the metrics, and `skin train`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from decoder.deconv import DeconvDecoder
from decoder.metrics import ave_rel_err, evaluate
from decoder.oracle import oracle_decode
from decoder.registry import load_decoder
from skin.cli import main
from skin.constants import DEFAULT_CONSTANTS

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels


def _crosstalk(strength: float) -> np.ndarray:
    import importlib.util

    spec = importlib.util.spec_from_file_location("synthdata", Path(__file__).with_name(
        "conftest.py"))
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    m: np.ndarray = module.crosstalk_matrix(strength)
    return m


def test_oracle_is_exact_without_noise(synth: Any) -> None:
    r, f = synth(50, strength=0.08, noise=False)
    out = oracle_decode(r, _crosstalk(0.08))
    assert np.max(np.abs(out.force_N - f)) < 1e-8


def test_deconv_learns_the_crosstalk_inverse(synth: Any) -> None:
    r, f = synth(400, strength=0.08, noise=False)
    decoder = DeconvDecoder(alpha=1e-12).fit(r, f)
    np.testing.assert_allclose(decoder.unmix_, np.linalg.inv(_crosstalk(0.08)), atol=1e-6)


def test_near_singular_crosstalk_stays_finite(synth: Any) -> None:
    s = 1 / (2 * np.sqrt(2)) - 1e-6  # M = I + s*A is singular at 1/(2*sqrt(2))
    assert np.linalg.cond(_crosstalk(s)) > 1e5
    r, f = synth(300, strength=s, seed=4, fz_max=3.5)
    out = DeconvDecoder().fit(r, f).decode(r)
    assert np.all(np.isfinite(out.force_N))
    analytic_err = evaluate(f, oracle_decode(r, np.eye(9)).force_N).rmse_N
    assert evaluate(f, out.force_N, out.valid).rmse_N < analytic_err


def test_metrics_by_hand() -> None:
    true = np.zeros((1, 9, 3))
    pred = np.zeros((1, 9, 3))
    true[0, :, 2] = [1, 2, 4, 0.1, 5, 5, 5, 5, 0.0]
    pred[0, :, 2] = [1.1, 2, 4, 0.2, 5, 5, 5, 5, 0.3]
    assert abs(ave_rel_err(true[..., 2], pred[..., 2]) - 100 * (0.1 + 1.0) / 8) < 1e-12
    report = evaluate(true, pred, mode="z", constants=DEFAULT_CONSTANTS)
    assert abs(report.ave_rel_err_floored_pct - 100 * 0.1 / 7) < 1e-12
    assert abs(report.max_rel_err_floored_pct - 10.0) < 1e-9
    assert abs(report.max_abs_err_N - 0.3) < 1e-12
    assert report.compared == 9 and report.masked == 0
    valid = np.ones((1, 9), bool)
    valid[0, 0] = False
    assert evaluate(true, pred, valid).masked == 1


def test_skin_train_writes_a_loadable_model(tmp_path: Path, synth: Any, capsys: Any) -> None:
    from skin.dataset import Dataset, write_dataset

    r, f = synth(300, seed=7)
    meta = {"scene": {"name": "synthetic"}, "seed": 7, "effects": [],
            "constants": DEFAULT_CONSTANTS.to_dict(), "mode": "z"}
    write_dataset(tmp_path / "d.npz", Dataset(r[:, None], f[:, None], meta))
    model = tmp_path / "m.msgpack"
    assert main(["train", "lm-mlp", "--data", str(tmp_path / "d.npz"), "--hidden", "9",
                 "-o", str(model)]) == 0
    out = capsys.readouterr().out
    assert "trained lm-mlp on 300 samples" in out
    assert "domain: pattern and departure checks calibrated on held-out rows" in out
    decoder = load_decoder(model)
    assert decoder.decode(r).valid.mean() >= 0.95
    assert main(["train", "analytic", "--data", str(tmp_path / "d.npz"), "--hidden", "3",
                 "-o", str(model)]) == 1
    assert "--hidden" in capsys.readouterr().err
