"""The dataset file: byte-identical per seed, validated on read, never pickled."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import pytest

from sim import generate_dataset, load_scene
from skin.constants import DEFAULT_CONSTANTS
from skin.dataset import Dataset, read_dataset, write_dataset
from skin.errors import ConfigError, DatasetError

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels


def test_same_seed_same_bytes_other_seed_other_bytes(tmp_path: Path) -> None:
    paths = [tmp_path / f"{i}.npz" for i in range(3)]
    for path, seed in zip(paths, (4, 4, 5), strict=True):
        write_dataset(path, generate_dataset("paper", 300, seed))
    a, b, c = (p.read_bytes() for p in paths)
    assert a == b and a != c


def test_round_trip_and_meta(tmp_path: Path) -> None:
    ds = generate_dataset(load_scene("hard"), 50, 3)
    write_dataset(tmp_path / "d.npz", ds)
    back = read_dataset(tmp_path / "d.npz")
    np.testing.assert_array_equal(back.resistance_ohm, ds.resistance_ohm)
    np.testing.assert_array_equal(back.force_N, ds.force_N)
    assert back.meta == json.loads(json.dumps(ds.meta))
    assert back.meta["seed"] == 3 and back.meta["mode"] == "xyz"
    assert back.meta["effects"] == ["elastic_crosstalk", "hysteresis", "drift", "noise", "faults"]
    assert back.meta["constants"] == DEFAULT_CONSTANTS.to_dict()
    assert back.resistance_ohm.shape == (50, 2, 9, 3)
    with np.load(tmp_path / "d.npz", allow_pickle=False) as npz:
        assert npz["meta"].shape == ()


def test_paper_dataset_shape() -> None:
    ds = generate_dataset("paper", 10, 0)
    assert ds.resistance_ohm.shape == (10, 1, 9, 1) and ds.force_N.shape == (10, 1, 9, 3)


@pytest.mark.parametrize("n", [-1, 0, 2.5])
def test_bad_sample_count(n: object) -> None:
    with pytest.raises(ConfigError, match=r"^n: "):
        generate_dataset("paper", n, 0)  # type: ignore[arg-type]


def write_raw(path: Path, arrays: dict[str, np.ndarray]) -> None:
    with zipfile.ZipFile(path, "w") as zf:
        for name, array in arrays.items():
            with zf.open(f"{name}.npy", "w") as member:
                np.lib.format.write_array(member, array, allow_pickle=False)


def test_read_rejects_bad_files(tmp_path: Path) -> None:
    good = generate_dataset("paper", 4, 0)
    meta = np.array(json.dumps(good.meta))
    cases = {
        "missing": {"resistance_ohm": good.resistance_ohm, "meta": meta},
        "dtype": {"resistance_ohm": good.resistance_ohm.astype(np.float32),
                  "force_N": good.force_N, "meta": meta},
        "shape": {"resistance_ohm": good.resistance_ohm, "force_N": good.force_N[:3],
                  "meta": meta},
        "meta": {"resistance_ohm": good.resistance_ohm, "force_N": good.force_N,
                 "meta": np.array("{not json")},
    }
    messages = {"missing": "missing force_N", "dtype": "float64", "shape": "force_N must be",
                "meta": "not valid JSON"}
    for name, arrays in cases.items():
        path = tmp_path / f"{name}.npz"
        write_raw(path, arrays)
        with pytest.raises(DatasetError, match=messages[name]):
            read_dataset(path)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(DatasetError, match=r"junk\.npz: not an \.npz \(zip\) archive"):
        read_dataset(tmp_path / "junk.npz")


def test_dataset_checks_its_arrays() -> None:
    with pytest.raises(DatasetError, match="resistance_ohm must be"):
        Dataset(np.zeros((2, 1, 8, 1)), np.zeros((2, 1, 8, 3)), {})
