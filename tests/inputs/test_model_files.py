"""Model files damaged on purpose, in their msgpack structure and in their bytes: one line
naming the file and the field, never a model built from them."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from decoder.registry import create_decoder, load_decoder
from skin.errors import ModelFileError
from tests.inputs.conftest import examples
from tests.inputs.hostile import (
    fingerprint,
    message_of,
    mutate_bytes,
    mutate_document,
    refused,
    run,
)


@pytest.fixture(scope="module")
def models(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    """A trained model of each kind that has state, as its file's bytes."""
    from sim import generate_dataset

    folder = tmp_path_factory.mktemp("models")
    ds = generate_dataset("paper", 120, 1)
    out = {}
    for name, params in (("deconv", {}), ("lm-mlp", {"hidden": 3, "max_epochs": 3}),
                         ("analytic", {"r0_ohm": [1000.0]})):
        model = create_decoder(name, **params).fit(ds.resistance_ohm, ds.force_N)
        model.save(folder / f"{name}.msgpack")
        out[name] = (folder / f"{name}.msgpack").read_bytes()
    return out


def _load(path: Path) -> None:
    message = message_of(lambda: load_decoder(path), ModelFileError)
    assert message is None or ("\n" not in message and message.startswith(str(path))), message


def _hostile_tree(doc: Any, draw: Any) -> Any:
    kind = draw(st.sampled_from(("document", "bytes-key", "array")))
    if kind == "bytes-key":
        doc["params"][b"r0_ohm"] = doc["params"].pop("r0_ohm", None)
        return doc
    if kind == "array":
        arrays = [(k, v) for k, v in doc["state"].items()
                  if isinstance(v, dict) and set(v) == {"dtype", "shape", "data"}]
        if arrays:
            _, array = draw(st.sampled_from(arrays))
            field = draw(st.sampled_from(("shape", "dtype", "data")))
            array[field] = draw(st.sampled_from((
                [10**12, 10**12], [-1], [2**63], "|O", "<f4", ">f8", b"", b"\x00" * 7,
                np.full(4, np.nan).tobytes(), [], "x", None)))
            return doc
    return mutate_document(doc, draw)


@examples(60)
@given(data=st.data(), name=st.sampled_from(("deconv", "lm-mlp", "analytic")))
def test_a_model_damaged_in_its_fields(tmp_path_factory: pytest.TempPathFactory,
                                       models: dict[str, bytes], data: st.DataObject,
                                       name: str) -> None:
    folder = tmp_path_factory.mktemp("model")
    doc = _hostile_tree(msgpack.unpackb(models[name], raw=False), data.draw)
    path = folder / "m.msgpack"
    try:
        path.write_bytes(msgpack.packb(doc, use_bin_type=True))
    except (TypeError, ValueError, OverflowError):
        return  # msgpack cannot even write it (a float nested in a Deep, a 2**64 int)
    before = fingerprint(folder)
    _load(path)
    assert fingerprint(folder) == before


@examples(30)
@given(data=st.data(), name=st.sampled_from(("deconv", "lm-mlp")))
def test_a_model_damaged_in_its_bytes(tmp_path_factory: pytest.TempPathFactory,
                                      models: dict[str, bytes], data: st.DataObject,
                                      name: str) -> None:
    path = tmp_path_factory.mktemp("model") / "m.msgpack"
    path.write_bytes(mutate_bytes(models[name], data.draw))
    _load(path)


@pytest.mark.parametrize(("change", "field"), [
    (lambda d: d["params"].__setitem__(b"r0_ohm", d["params"].pop("r0_ohm")), "params"),
    (lambda d: d["params"].__setitem__("r0_ohm", "x"), "params.r0_ohm"),
    (lambda d: d["params"]["constants"].__setitem__("adc_bits", True),
     "params.constants.adc_bits"),
    (lambda d: d["params"].__setitem__("alpha", -1.0), "params.alpha"),
])
def test_the_field_is_named(tmp_path: Path, models: dict[str, bytes], change: Any,
                            field: str) -> None:
    doc = msgpack.unpackb(models["deconv"], raw=False)
    change(doc)
    path = tmp_path / "m.msgpack"
    path.write_bytes(msgpack.packb(doc, use_bin_type=True))
    result = run("eval", path, tmp_path / "absent.npz")
    refused(result)
    assert f"{path}: {field}" in result.lines[0]


@pytest.mark.parametrize(("change", "field"), [
    ({"heldout_floored_pct": "x"}, "meta.calibration.heldout_floored_pct"),
    ({"heldout_floored_pct": float("nan")}, "meta.calibration.heldout_floored_pct"),
    ({"mode": 3}, "meta.calibration.mode"),
    ({"node_id": True}, "meta.calibration.node_id"),
    ({"tare": 5}, "meta.calibration.tare"),
    ({"tare": {"rest_ohm": np.zeros((9, 3))}}, "meta.calibration.tare.rest_ohm"),
    ({"tare": {"rest_N": -1}}, "meta.calibration.tare.rest_N"),
])
def test_a_calibration_report_is_checked_field_by_field(change: dict[str, Any],
                                                        field: str) -> None:
    from decoder.calibration import check_calibration_meta

    report = {"heldout_floored_pct": 1.0, "mode": "xyz", "node_id": 1, "flagged_pct": 0.0,
              "tare": {"rest_ohm": None, "rest_N": 0.01}}
    assert check_calibration_meta(dict(report), "m.msgpack")
    with pytest.raises(ModelFileError, match=rf"^m\.msgpack: {field}: "):
        check_calibration_meta({**report, **change}, "m.msgpack")
