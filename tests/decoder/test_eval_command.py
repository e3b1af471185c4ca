"""`skin eval MODEL D.npz`: a decoder's held-out error, the masked taxels by reason, clear
refusals. Datasets are written from the synthetic data of conftest.py (no simulator)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from decoder.deconv import DeconvDecoder
from decoder.metrics import evaluate, rmse_per_axis
from decoder.protocol import Decoded
from skin.cli import main
from skin.constants import DEFAULT_CONSTANTS
from skin.dataset import Dataset, write_dataset
from tests.decoder.conftest import F64, make_data

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels


def _dataset(path: Path, r: F64, f: F64) -> Path:
    """(samples, 9, P) arrays as a one-patch dataset file."""
    mode = "z" if r.shape[-1] == 1 else "xyz"
    meta = {"scene": "synthetic", "seed": 0, "effects": [], "mode": mode,
            "constants": DEFAULT_CONSTANTS.to_dict()}
    write_dataset(path, Dataset(r[:, None].copy(), f[:, None].copy(), meta))
    return path


def _eval(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, dict[str, object],
                                                                   str, str]:
    out = Path(argv[-1]).with_suffix(".json")
    code = main(["eval", *argv, "--json", str(out)])
    captured = capsys.readouterr()
    return code, (json.loads(out.read_text()) if code in (0, 3) else {}), captured.out, \
        captured.err


def test_a_model_file_on_held_out_data(tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    r_train, f_train = make_data(400, seed=11)
    r_test, f_test = make_data(60, seed=12)
    model = tmp_path / "deconv.msgpack"
    DeconvDecoder().fit(r_train, f_train).save(model)
    code, record, out, _ = _eval(capsys, str(model), str(_dataset(tmp_path / "test.npz",
                                                                  r_test, f_test)))
    assert code == 0
    decoded = DeconvDecoder.load(model).decode(r_test)
    expected = evaluate(f_test, decoded.force_N, decoded.valid, mode="z")
    assert record["metrics"] == pytest.approx(expected.to_dict(), rel=1e-12)
    assert record["rmse_per_axis_N"] == {"z": pytest.approx(expected.rmse_N, rel=1e-12)}
    assert (record["decoder"], record["mode"], record["samples"]) == ("deconv", "z", 60)
    assert record["invalid"] == {"taxels": 0, "share": 0.0, "by_reason": {}}
    assert out.startswith(f"{model} (deconv) on {tmp_path / 'test.npz'}: 60 samples x 1 "
                          "patch, z-only (Fz compared); the figures cover 540 of 540 taxels "
                          "(100.00 %)\n")
    assert record["covered"] == {"taxels": 540, "share": 1.0}
    assert f"  RMSE                     {expected.rmse_N:.4f} N = " in out
    assert "  floored (|F| >= 0.25 N)  " in out


def test_a_decoder_name_and_masked_taxels_by_reason(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    r, f = make_data(20, pillars=3, seed=13)
    r[0, 0, 1] = np.inf  # open
    r[1, 2, 0] = 0.0  # short
    r[2, 4, 2] = np.nan  # non-finite
    r[3, :, :] = np.inf  # a whole sample open: 9 taxels
    code, record, out, _ = _eval(capsys, "analytic", str(_dataset(tmp_path / "d.npz", r, f)))
    assert code == 0
    taxels = 20 * 9
    assert record["invalid"] == {
        "taxels": 12, "share": 12 / taxels,
        "by_reason": {"NON_FINITE": {"taxels": 1, "share": 1 / taxels},
                      "OPEN": {"taxels": 10, "share": 10 / taxels},
                      "SHORT": {"taxels": 1, "share": 1 / taxels}}}
    assert record["metrics"]["masked"] == 12  # type: ignore[index]
    assert set(record["rmse_per_axis_N"]) == {"x", "y", "z"}  # type: ignore[arg-type]
    assert "masked taxels            12 of 180 (6.67 %): NON_FINITE 0.56 %, OPEN 5.56 %, " \
           "SHORT 0.56 %" in out


def test_reason_codes_it_does_not_know_yet_still_show(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str],
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    r, f = make_data(4, seed=14)

    class Future(DeconvDecoder):
        name = "future"

        def decode(self, resistance_ohm: object) -> Decoded:
            reason = np.zeros((4, 1, 9), np.uint8)
            reason[0, 0, 3] = 42  # a code added after this command was written
            return Decoded(np.zeros((4, 1, 9, 3)), reason == 0, reason)

    monkeypatch.setattr("decoder.registry.available_decoders", lambda: ("future",))
    monkeypatch.setattr("decoder.registry.create_decoder", lambda name: Future())
    code, record, _, _ = _eval(capsys, "future", str(_dataset(tmp_path / "d.npz", r, f)))
    assert code == 0
    assert record["invalid"]["by_reason"] == {  # type: ignore[index]
        "UNKNOWN(42)": {"taxels": 1, "share": 1 / 36}}


def test_other_sensor_constants_are_named(tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    r, f = make_data(200, seed=18)
    model = tmp_path / "soft.msgpack"
    soft = dataclasses.replace(DEFAULT_CONSTANTS, youngs_modulus_pa=20e6)
    DeconvDecoder(constants=soft).fit(r, f).save(model)
    code, _, _, err = _eval(capsys, str(model), str(_dataset(tmp_path / "d.npz", r[:9], f[:9])))
    assert code == 0
    assert f"WARNING skin.commands.eval: {model} assumes other sensor constants than the " \
           "dataset's (youngs_modulus_pa): the error includes that mismatch" in err


def test_clear_refusals(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    z = _dataset(tmp_path / "z.npz", *make_data(5, seed=15))
    xyz = _dataset(tmp_path / "xyz.npz", *make_data(5, pillars=3, seed=16))
    model = tmp_path / "z.msgpack"
    DeconvDecoder().fit(*make_data(200, seed=17)).save(model)
    cases = [
        ([str(model), str(xyz)], f"{xyz}: 3-axis resistances (3 pillars per taxel), but "
                                 f"{model} was fitted on z-only input (1 pillar); evaluate it "
                                 "on a dataset of a z-only scene"),
        (["deconv", str(z)], f"MODEL: decoder 'deconv' needs training first: `skin train "
                             f"deconv --data TRAIN.npz -o M.msgpack`, then `skin eval "
                             f"M.msgpack {z}`"),
        (["nothing", str(z)], "MODEL: 'nothing' is neither a model file nor a decoder name "
                              "(decoders: analytic, deconv, lm-mlp, hybrid"),
        (["analytic", str(tmp_path / "absent.npz")], "absent.npz: no such file"),
    ]
    for argv, problem in cases:
        assert main(["eval", *argv, "--json", str(tmp_path / "e.json")]) == 1
        err = capsys.readouterr().err
        assert err.startswith("skin: error: ") and problem in err and err.count("\n") == 1
    assert not (tmp_path / "e.json").exists()
    assert rmse_per_axis(np.zeros((1, 9, 3)), np.ones((1, 9, 3)), mode="xyz") == \
        {"x": 1.0, "y": 1.0, "z": 1.0}


def test_a_run_whose_every_taxel_is_masked_is_no_result(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Not a perfect score: the first line says nothing was covered; exit 3, and no figure
    (floored, max relative) reads 0 %."""
    r, f = make_data(30, pillars=3, seed=19)
    r[:] = np.inf  # every pillar open
    code, record, out, _ = _eval(capsys, "analytic", str(_dataset(tmp_path / "d.npz", r, f)))
    assert code == 3
    first = out.splitlines()[0]
    assert first == (f"analytic (analytic) on {tmp_path / 'd.npz'}: 30 samples x 1 patch, "
                     "3-axis: no result: every taxel masked (270 of 270: OPEN 100.00 %), so no "
                     "error covers anything")
    assert len(out.splitlines()) == 1
    assert record["covered"] == {"taxels": 0, "share": 0.0}
    metrics = record["metrics"]
    assert metrics["ave_rel_err_floored_pct"] is None  # type: ignore[index]
    assert metrics["max_rel_err_floored_pct"] is None  # type: ignore[index]


def test_a_figure_over_nothing_is_nan_never_zero() -> None:
    nothing = evaluate(np.ones((2, 9, 3)), np.ones((2, 9, 3)), np.zeros((2, 9), bool),
                       mode="xyz")
    assert np.isnan(nothing.ave_rel_err_floored_pct) and np.isnan(nothing.rmse_N)
    assert (nothing.covered, nothing.covered_share, nothing.taxels) == (0, 0.0, 18)
    at_rest = evaluate(np.zeros((2, 9, 3)), np.zeros((2, 9, 3)), mode="xyz")
    assert np.isnan(at_rest.ave_rel_err_floored_pct) and at_rest.covered_share == 1.0
