"""Model files: round trip, and every corrupt or hostile file refused with a named field."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from decoder.deconv import DeconvDecoder
from decoder.modelfile import read_model, write_model
from decoder.registry import load_decoder
from skin.errors import ModelFileError

FILES = Path(__file__).resolve().parents[1] / "files"

CORRUPT = {
    "model_truncated": "not a valid msgpack",
    "model_not_msgpack": "not a valid msgpack",
    "model_wrong_schema": "schema",
    "model_future_version": "version",
    "model_bad_dtype": "state.unmix_.dtype",
    "model_shape_mismatch": "state.unmix_.data",
    "model_nan_weights": "NaN",
    "model_huge_shape": "state.unmix_.shape",
    "model_wrong_state_shape": "state.unmix_",
    "model_unknown_name": "name",
    "model_ext_type": "not a valid msgpack",
    "model_top_level_list": "top level",
    "model_trailing_bytes": "not a valid msgpack",
}


@pytest.mark.parametrize(("name", "field"), sorted(CORRUPT.items()))
def test_corrupt_file_is_refused_naming_the_field(name: str, field: str) -> None:
    path = FILES / f"{name}.msgpack"
    with pytest.raises(ModelFileError, match=field.replace(".", r"\.")):
        load_decoder(path)
    with pytest.raises(ModelFileError):
        DeconvDecoder.load(path)


def test_arrays_and_scalars_round_trip(tmp_path: Path) -> None:
    state = {"a_": np.arange(6.0).reshape(2, 3), "b_": np.array([True, False]), "n_": 3}
    write_model(tmp_path / "m.msgpack", "x", {"p": 1.5, "q": None, "d": {"k": "v"}}, state)
    content = read_model(tmp_path / "m.msgpack")
    assert content.name == "x"
    assert content.params == {"p": 1.5, "q": None, "d": {"k": "v"}}
    np.testing.assert_array_equal(content.state["a_"], state["a_"])
    np.testing.assert_array_equal(content.state["b_"], state["b_"])
    assert content.state["n_"] == 3


def test_loading_a_model_of_another_class_is_refused(tmp_path: Path, synth) -> None:  # type: ignore[no-untyped-def]
    from decoder.lmmlp import LMMLPDecoder

    r, f = synth(50)
    DeconvDecoder().fit(r, f).save(tmp_path / "d.msgpack")
    with pytest.raises(ModelFileError, match="name"):
        LMMLPDecoder.load(tmp_path / "d.msgpack")


def test_failed_write_leaves_no_file(tmp_path: Path) -> None:
    with pytest.raises(TypeError):
        write_model(tmp_path / "m.msgpack", "x", {"bad": np.zeros(2, np.complex128)}, {})
    assert not list(tmp_path.iterdir())
