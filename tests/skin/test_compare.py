"""`skin compare FORCES --reference REF`: decoded forces against the reference, joined by
SYNC counter or by time, with the share of the taxels the figures cover."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from decoder.metrics import evaluate
from skin.cli import main
from skin.reference import ReferenceWriter

PERIOD = 0.01


def _truth(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    force = np.zeros((n, 9, 3))
    force[..., 2] = rng.uniform(0, 5, (n, 9))
    force[..., :2] = rng.uniform(-0.5, 0.5, (n, 9, 2))
    return force


def _decode_npz(path: Path, t: np.ndarray, counter: np.ndarray, force: np.ndarray,
                valid: np.ndarray, patch: int = 1) -> Path:
    n = len(t)
    np.savez(path, cycle=np.arange(n), sync_counter=counter.astype(np.uint8), time_s=t,
             patch=np.full(n, patch, np.uint8), force_node=np.full(n, patch + 64, np.uint8),
             complete=valid.all(axis=1), force_N=force, valid=valid,
             reason=np.where(valid, 0, 8).astype(np.uint8))
    return path


def _decode_csv(path: Path, t: np.ndarray, counter: np.ndarray, force: np.ndarray,
                valid: np.ndarray) -> Path:
    lines = ["cycle,sync_counter,time_s,patch,force_node,taxel,fx_N,fy_N,fz_N,valid,reason,"
             "complete"]
    for k in range(len(t)):
        for taxel in range(9):
            fx, fy, fz = force[k, taxel].tolist()
            lines.append(f"{k},{counter[k]},{float(t[k])!r},1,65,{taxel},{fx!r},{fy!r},{fz!r},"
                         f"{int(valid[k, taxel])},OK,{int(valid[k].all())}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


@pytest.mark.parametrize("suffix", [".npz", ".csv"])
def test_joined_by_counter_and_the_figures_say_what_they_cover(
        tmp_path: Path, suffix: str, capsys: pytest.CaptureFixture[str]) -> None:
    n = 120
    truth = _truth(n, 1)
    t = 50.0 + PERIOD * np.arange(n)
    counter = np.arange(n) % 240 + 1
    ref = ReferenceWriter(tmp_path / "truth.csv")
    for k in range(n):
        if k % 10 != 3:  # the reference lost every tenth sample
            ref.write(t[k] - 1000.0, counter[k], 1, truth[k])  # its own clock
    ref.close()
    decoded = truth + np.random.default_rng(2).normal(0, 0.02, truth.shape)
    valid = np.ones((n, 9), bool)
    valid[::7, 4] = False  # some taxels masked
    write = _decode_npz if suffix == ".npz" else _decode_csv
    forces = write(tmp_path / f"forces{suffix}", t, counter, decoded, valid)
    code = main(["compare", str(forces), "--reference", str(tmp_path / "truth.csv"), "--json",
                 str(tmp_path / "c.json")])
    assert code == 0
    out = capsys.readouterr().out.splitlines()
    keep = np.array([k % 10 != 3 for k in range(n)])
    want = evaluate(truth[keep], decoded[keep], valid[keep], mode="xyz")
    assert out[0] == (f"{forces} against {tmp_path / 'truth.csv'}: {keep.sum():,} samples "
                      f"joined; the figures cover {want.covered:,} of {want.taxels:,} taxels "
                      f"({100 * want.covered_share:.2f} %)")
    assert out[1].startswith(f"patch 1: {keep.sum()} of {keep.sum()} reference samples joined "
                             "(by SYNC counter); Fx, Fy, Fz over")
    record = json.loads((tmp_path / "c.json").read_text())["patches"]["1"]
    assert record["ave_rel_err_floored_pct"] == pytest.approx(want.ave_rel_err_floored_pct,
                                                              rel=1e-9)
    assert record["rmse_N"] == pytest.approx(want.rmse_N, rel=1e-9)


def test_nothing_decoded_is_no_result(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    n = 30
    truth = _truth(n, 3)
    t = PERIOD * np.arange(n)
    counter = np.arange(n) + 1
    ref = ReferenceWriter(tmp_path / "truth.csv")
    for k in range(n):
        ref.write(t[k], counter[k], 1, truth[k])
    ref.close()
    forces = _decode_npz(tmp_path / "f.npz", t, counter, np.zeros_like(truth),
                         np.zeros((n, 9), bool))
    assert main(["compare", str(forces), "--reference", str(tmp_path / "truth.csv"),
                 "--clock-offset-ms", "0"]) == 3
    first = capsys.readouterr().out.splitlines()[0]
    assert first.endswith(": no result: every joined taxel was masked (or none joined), so no "
                          "error covers anything")


@pytest.mark.parametrize(("content", "message"), [
    ("a,b\n1,2\n", "row 1: not skin decode's header"),
    ("cycle,sync_counter,time_s,patch,force_node,taxel,fx_N,fy_N,fz_N,valid,reason,complete\n"
     "0,1,0.0,1,65,0,0,0,0,1,OK,1\n", "row 2: 1 taxel rows, not 9 per sample"),
])
def test_bad_forces_in_one_line(tmp_path: Path, content: str, message: str,
                                capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "f.csv"
    bad.write_text(content, encoding="utf-8")
    ref = ReferenceWriter(tmp_path / "truth.csv")
    ref.write(0.0, 1, 1, np.zeros((9, 3)))
    ref.close()
    assert main(["compare", str(bad), "--reference", str(tmp_path / "truth.csv")]) == 1
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
