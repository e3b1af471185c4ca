"""Datasets (.npz) and reference forces (.csv, .npz) damaged on purpose: one line naming
the file; declared sizes checked before anything is allocated; nothing learned from data
that holds nothing to learn."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from skin.errors import ReferenceFileError
from skin.reference import read_reference
from tests.inputs.conftest import examples
from tests.inputs.hostile import answered, fingerprint, message_of, mutate_bytes, refused, run


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("data") / "d.npz"
    assert run("sim", "dataset", "paper", "-n", "40", "-o", path).code == 0
    return path


def _npy(array: np.ndarray, shape: tuple[int, ...] | None = None) -> bytes:
    """``array`` as .npy bytes; ``shape``: the header declares this one instead."""
    out = io.BytesIO()
    np.lib.format.write_array(out, array, allow_pickle=True)
    data = out.getvalue()
    if shape is not None:
        data = data.replace(repr(array.shape).encode(), repr(shape).encode().ljust(
            len(repr(array.shape))), 1)
        header_end = data.index(b"\n") + 1
        fixed = io.BytesIO()
        np.lib.format.write_array_header_1_0(fixed, {"descr": array.dtype.str,
                                                     "fortran_order": False, "shape": shape})
        data = fixed.getvalue() + data[header_end:]
    return data


def _archive(members: dict[str, bytes]) -> bytes:
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return out.getvalue()


def _members(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as npz:
        return {k: npz[k] for k in npz.files}


def _damaged(members: dict[str, np.ndarray], draw: Any) -> dict[str, bytes]:
    arrays = {f"{k}.npy": _npy(v) for k, v in members.items()}
    r, f = members["resistance_ohm"], members["force_N"]
    name = draw(st.sampled_from(("resistance_ohm.npy", "force_N.npy", "meta.npy")))
    kind = draw(st.sampled_from(("values", "shape", "dtype", "header", "missing", "meta",
                                 "object", "same")))
    if kind == "values" and name != "meta.npy":
        a = (r if name.startswith("res") else f).copy()
        a.flat[draw(st.integers(0, a.size - 1))] = draw(st.sampled_from(
            (np.nan, np.inf, -np.inf, 1e300, -1e300, -1.0)))
        arrays[name] = _npy(a)
    elif kind == "shape":
        arrays[name] = _npy(draw(st.sampled_from((r[:, :, :5], f[:-1], r.reshape(-1),
                                                  np.zeros((0, 1, 9, 1)), r[..., None]))))
    elif kind == "dtype":
        arrays[name] = _npy(draw(st.sampled_from((r.astype(np.float32), f.astype(">f8"),
                                                  r.astype(np.int64), np.array(["x"])))))
    elif kind == "header":
        arrays[name] = _npy(r if name.startswith("res") else f, draw(st.sampled_from(
            ((10**12, 1, 9, 1), (40, 1, 9, 10**9), (2**40,), (40, 1, 9, 3)))))
    elif kind == "missing":
        del arrays[name]
    elif kind == "meta":
        arrays["meta.npy"] = _npy(np.array(draw(st.sampled_from((
            "[" * 100_000, "NaN", '{"mode": "z"}', "[]", '{"constants": 5, "mode": "z"}',
            json.dumps({**json.loads(str(members["meta"])), "constants": {"adc_bits": True}}),
            "\x00")))))
    elif kind == "object":
        arrays[name] = _npy(np.array([object()], dtype=object))
    else:
        arrays["force_N.npy"] = _npy(np.repeat(f[:1], len(f), axis=0))
    return arrays


def _commands(path: Path, out: Path) -> list[tuple[str, ...]]:
    return [("eval", "analytic", str(path)), ("train", "deconv", "--data", str(path), "-o",
                                              str(out))]


@examples(50)
@given(data=st.data())
def test_a_dataset_damaged_in_its_arrays(tmp_path_factory: pytest.TempPathFactory,
                                         dataset: Path, data: st.DataObject) -> None:
    folder = tmp_path_factory.mktemp("dataset")
    path = folder / "d.npz"
    path.write_bytes(_archive(_damaged(_members(dataset), data.draw)))
    before = fingerprint(folder)
    for argv in _commands(path, folder / "out" / "m.msgpack"):
        (folder / "out").mkdir(exist_ok=True)
        result = run(*argv)
        answered(result)
        if result.code:
            assert str(path) in result.lines[0], result.lines[0]
            assert not (folder / "out" / "m.msgpack").exists()
        (folder / "out" / "m.msgpack").unlink(missing_ok=True)
    assert fingerprint(folder) == before


@examples(30)
@given(data=st.data())
def test_a_dataset_damaged_in_its_bytes(tmp_path_factory: pytest.TempPathFactory,
                                        dataset: Path, data: st.DataObject) -> None:
    path = tmp_path_factory.mktemp("dataset") / "d.npz"
    path.write_bytes(mutate_bytes(dataset.read_bytes(), data.draw))
    answered(run("eval", "analytic", path))


@pytest.mark.parametrize("what", ["npy", "rows", "identical", "huge"])
def test_the_issues_dataset_examples(tmp_path: Path, dataset: Path, what: str) -> None:
    members = _members(dataset)
    path = tmp_path / "d.npz"
    if what == "npy":
        np.save(tmp_path / "d.npy", members["resistance_ohm"])
        (tmp_path / "d.npy").rename(path)
    else:
        arrays = {f"{k}.npy": _npy(v) for k, v in members.items()}
        if what == "rows":
            arrays["resistance_ohm.npy"] = _npy(members["resistance_ohm"], (10**12, 1, 9, 1))
        elif what == "identical":
            for key in ("resistance_ohm", "force_N"):
                arrays[f"{key}.npy"] = _npy(np.repeat(members[key][:1], 200, axis=0))
        else:
            arrays["force_N.npy"] = _npy(members["force_N"] * 1e300)
        path.write_bytes(_archive(arrays))
    result = run("train", "lm-mlp", "--data", path, "-o", tmp_path / "m.msgpack")
    refused(result)
    assert str(path) in result.lines[0]
    assert not (tmp_path / "m.msgpack").exists()


REFERENCE = ("time_s,sync,node_id,taxel,fx_N,fy_N,fz_N\n" + "".join(
    f"{0.01 * s!r},{s + 1},1,{t},0.0,0.0,{0.1 * t!r}\n" for s in range(3) for t in range(9)))


def _reference(path: Path) -> None:
    message = message_of(lambda: read_reference(path), ReferenceFileError)
    assert message is None or ("\n" not in message and message.startswith(str(path))), message


@examples(40)
@given(data=st.data(), value=st.sampled_from(("nan", "inf", "-1", "1e400", "x", "", "128",
                                               "1.5", "0x10", "\x00", '"', "1e300")))
def test_a_reference_csv_damaged(tmp_path_factory: pytest.TempPathFactory,
                                 data: st.DataObject, value: str) -> None:
    path = tmp_path_factory.mktemp("reference") / "ref.csv"
    if data.draw(st.booleans()):
        rows = [line.split(",") for line in REFERENCE.splitlines()]
        row = data.draw(st.integers(0, len(rows) - 1))
        rows[row][data.draw(st.integers(0, 6))] = value
        path.write_text("\n".join(",".join(r) for r in rows) + "\n")
    else:
        path.write_bytes(mutate_bytes(REFERENCE.encode(), data.draw))
    _reference(path)


@examples(20)
@given(data=st.data())
def test_a_reference_npz_damaged(tmp_path_factory: pytest.TempPathFactory,
                                 data: st.DataObject) -> None:
    path = tmp_path_factory.mktemp("reference") / "ref.npz"
    columns = {"time_s": np.arange(9) * 0.01, "node_id": np.ones(9), "taxel": np.arange(9),
               "fx_N": np.zeros(9), "fy_N": np.zeros(9), "fz_N": np.ones(9)}
    members = {f"{k}.npy": _npy(v) for k, v in columns.items()}
    name = data.draw(st.sampled_from(sorted(members)))
    members[name] = data.draw(st.sampled_from((
        _npy(np.array([object()], dtype=object)), _npy(np.zeros(9), (10**12,)),
        _npy(np.zeros((3, 3))), b"garbage", _npy(np.array(["a"] * 9)),
        _npy(np.full(9, np.nan)))))
    path.write_bytes(_archive(members))
    _reference(path)
