"""Golden tests of `skin sim dataset`."""

from __future__ import annotations

from pathlib import Path

import pytest

from skin.cli import main
from skin.dataset import read_dataset
from skin.errors import ConfigError

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels

FILES = Path(__file__).parents[1] / "files"


def test_dataset_paper(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "paper.npz"
    assert main(["sim", "dataset", "paper", "-n", "100", "-o", str(out)]) == 0
    assert capsys.readouterr().out == (
        f"wrote {out}: 100 samples x 1 patches x 9 taxels x 1 pillars (scene paper, seed 0)\n"
    )
    ds = read_dataset(out)
    assert ds.meta["seed"] == 0 and ds.resistance_ohm.shape == (100, 1, 9, 1)


def test_dataset_from_path_with_seed(tmp_path: Path) -> None:
    out = tmp_path / "d.npz"
    scene = Path(__file__).parents[2] / "sim" / "scenes" / "slide.toml"
    assert main(["sim", "dataset", str(scene), "-n", "20", "--seed", "9", "-o", str(out)]) == 0
    assert read_dataset(out).meta["seed"] == 9


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([str(FILES / "sim_unknown_load.toml"), "-n", "5"],
         f"skin: error: {FILES / 'sim_unknown_load.toml'}: loads[0].kind: unknown load 'foo'; "
         "known: uniform_random, indenter, slide, grasp, idle, stick_slip\n"),
        ([str(FILES / "sim_unknown_effect.toml"), "-n", "5"],
         f"skin: error: {FILES / 'sim_unknown_effect.toml'}: effects.wobble: unknown effect "
         "'wobble'; known: elastic_crosstalk, hysteresis, drift, readout, noise, faults\n"),
        ([str(FILES / "sim_unknown_key.toml"), "-n", "5"],
         f"skin: error: {FILES / 'sim_unknown_key.toml'}: loads[0].radius_mm: unknown key; "
         "known: depth_max_m, fz_max_N, radius_m\n"),
        ([str(FILES / "sim_overstrain.toml"), "-n", "5"],
         f"skin: error: {FILES / 'sim_overstrain.toml'}: loads[0].fz_max_N: 20 "),
        ([str(FILES / "sim_bad_syntax.toml"), "-n", "5"],
         f"skin: error: {FILES / 'sim_bad_syntax.toml'}: scene: not valid TOML: "),
        (["nope", "-n", "5"], "skin: error: scene: unknown scene 'nope'"),
    ],
)
def test_errors_one_line_no_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    out = tmp_path / "out.npz"
    assert main(["sim", "dataset", *args, "-o", str(out)]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith(message)
    assert captured.err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_a_negative_count_is_a_usage_error(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as refused:
        main(["sim", "dataset", "paper", "-n", "-5", "-o", str(tmp_path / "out.npz")])
    assert refused.value.code == 2
    assert capsys.readouterr().err == (
        "skin sim dataset: error: argument -n: must be in 1..1000000000000, got '-5' (see "
        "skin sim dataset --help)\n")
    assert list(tmp_path.iterdir()) == []


def test_debug_reraises(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as info:
        main(["--debug", "sim", "dataset", str(FILES / "sim_overstrain.toml"), "-n", "5",
              "-o", str(tmp_path / "x.npz")])
    assert info.value.field == "loads[0].fz_max_N"
    assert info.value.__cause__ is not None
