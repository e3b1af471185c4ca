"""Model files: round trip (with the training domain and the metadata), version-1, -2 and -3
files, and every corrupt or hostile file refused with a named field."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest

from decoder.deconv import DeconvDecoder
from decoder.modelfile import read_model, write_model
from decoder.reasons import Reason
from decoder.registry import create_decoder, load_decoder
from skin.errors import ModelFileError

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels

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


def _doc(path: Path) -> dict[str, Any]:
    doc: dict[str, Any] = msgpack.unpackb(path.read_bytes(), raw=False)
    return doc


def _put(path: Path, doc: dict[str, Any]) -> Path:
    path.write_bytes(msgpack.packb(doc, use_bin_type=True))
    return path


@pytest.fixture(scope="module")
def saved(tmp_path_factory: pytest.TempPathFactory, synth: Any) -> dict[str, Path]:
    """deconv, lm-mlp and hybrid trained on loads up to 3 N, saved."""
    r, f = synth(300, seed=71, fz_max=3.0)
    folder = tmp_path_factory.mktemp("models")
    out = {}
    for name, params in (("deconv", {}), ("lm-mlp", {"max_epochs": 30}),
                         ("hybrid", {"max_epochs": 30})):
        path = folder / f"{name}.msgpack"
        create_decoder(name, **params).fit(r, f).save(path)
        out[name] = path
    return out


@pytest.mark.parametrize("name", ["deconv", "lm-mlp", "hybrid"])
def test_the_training_domain_and_metadata_round_trip(saved: dict[str, Path], synth: Any,
                                                     name: str) -> None:
    doc = _doc(saved[name])
    assert doc["version"] == 4 and "domain_" in doc["state"] and isinstance(doc["meta"], dict)
    loaded = load_decoder(saved[name])
    r, _ = synth(60, seed=72, fz_max=5.0)  # some taxels beyond the 3 N of training
    out = loaded.decode(r)
    assert (out.reason == Reason.EXTRAPOLATED).any() and out.valid.any()
    again = load_decoder(_put(saved[name].with_suffix(".copy"), doc))
    np.testing.assert_array_equal(again.decode(r).reason, out.reason)
    meta = loaded.meta()  # type: ignore[attr-defined]
    assert meta and set(meta) == set(again.meta())  # type: ignore[attr-defined]
    assert "crosstalk" in meta or "training" in meta


def _as_version_1(doc: dict[str, Any], params: tuple[str, ...], state: tuple[str, ...]) -> None:
    doc["version"] = 1
    del doc["meta"]
    for key in params:
        del doc["params"][key]
    for key in state:
        del doc["state"][key]


@pytest.mark.parametrize(("name", "params", "state"), [
    ("deconv", ("range_margin",), ("domain_",)),
    ("lm-mlp", ("goal_units",), ("hidden_", "unmix_", "domain_")),
    ("hybrid", ("goal_units", "alpha", "range_margin"),
     ("hidden_", "unmix_", "domain_", "residual_domain_", "use_residual_",
      "residual_threshold_")),
])
def test_version_1_files_still_load(saved: dict[str, Path], synth: Any, tmp_path: Path,
                                    name: str, params: tuple[str, ...],
                                    state: tuple[str, ...]) -> None:
    doc = _doc(saved[name])
    _as_version_1(doc, params, state)
    old = load_decoder(_put(tmp_path / "v1.msgpack", doc))
    r, _ = synth(20, seed=73, fz_max=3.0)
    out = old.decode(r)
    assert out.valid.all() and np.all(np.isfinite(out.force_N))
    assert old.meta() == {}  # type: ignore[attr-defined]


V3 = {mode: (FILES / f"model_lm_mlp_v3_{mode}.msgpack",
             FILES / f"model_lm_mlp_v3_{mode}_decoded.npz") for mode in ("z", "xyz")}
"""lm-mlp files written by version 3 (z-only and 3-axis, trained on presses up to 3 N), and what
they decoded then: resistances of presses up to 4.5 N, forces and reasons."""


@pytest.mark.parametrize("mode", ["z", "xyz"])
def test_version_3_files_still_load_and_decode_as_they_did(mode: str) -> None:
    model, decoded = V3[mode]
    old = load_decoder(model)
    then = np.load(decoded, allow_pickle=False)
    out = old.decode(then["resistance_ohm"])
    np.testing.assert_array_equal(out.reason, then["reason"])  # exact: integer flags
    # the forces were computed on another machine, whose BLAS sums in another order: a file
    # read by a new version decodes to within 1e-9 of what it decoded then, relative to its
    # largest force (the last bits of a sum are the processor's, not the file's)
    np.testing.assert_allclose(out.force_N, then["force_N"], rtol=1e-9,
                               atol=1e-9 * np.abs(then["force_N"]).max())
    assert (out.reason == Reason.EXTRAPOLATED).any() and out.valid.any()
    domain = old.domain_  # type: ignore[attr-defined]
    assert domain.density is not None and domain.pattern is None and domain.departure is None


def test_version_2_files_still_load_and_decode_as_they_did(saved: dict[str, Path], synth: Any,
                                                           tmp_path: Path) -> None:
    """Version 3 added hybrid's residual threshold and lm-mlp's per-taxel band: a version-2
    hybrid adds its residual as it is, a version-2 lm-mlp has only the per-component band."""
    doc = _doc(saved["hybrid"])
    doc["version"] = 2
    del doc["state"]["residual_threshold_"]
    old = load_decoder(_put(tmp_path / "hybrid-v2.msgpack", doc))
    assert not old.residual_threshold_.any()  # type: ignore[attr-defined]
    now = load_decoder(saved["hybrid"])
    now.residual_threshold_[:] = 0.0  # type: ignore[attr-defined]
    now._prepare()  # type: ignore[attr-defined]
    r, _ = synth(40, seed=76, fz_max=3.0)
    np.testing.assert_array_equal(old.decode(r).force_N,  # exact: both decoded here
                                  now.decode(r).force_N)
    doc = _doc(V3["xyz"][0])
    doc["version"] = 2
    del doc["state"]["domain_"]["taxel_band"]
    old = load_decoder(_put(tmp_path / "lm-v2.msgpack", doc))
    assert old.domain_.taxel_band is None  # type: ignore[attr-defined]
    r, _ = synth(60, seed=75, pillars=3, fz_max=5.0)
    then, now_out = old.decode(r), load_decoder(V3["xyz"][0]).decode(r)
    np.testing.assert_array_equal(then.force_N[now_out.valid],  # exact: both decoded here
                                  now_out.force_N[now_out.valid])
    assert not (now_out.valid & ~then.valid).any()  # the band only adds flags


def test_the_per_taxel_band_of_version_3_is_checked(tmp_path: Path) -> None:
    path = V3["xyz"][0]
    doc = _doc(path)
    assert set(doc["state"]["domain_"]) == {"inputs", "outputs", "density", "band", "taxel_band"}
    for damage, field in (
            (lambda b: b.__setitem__("limit", 0.0), "state.domain_.taxel_band.limit"),
            (lambda b: b.__setitem__("whiten", b["mean"]), "state.domain_.taxel_band.whiten"),
            (lambda b: b.__setitem__("extra", 1), "state.domain_.taxel_band")):
        bad = _doc(path)
        damage(bad["state"]["domain_"]["taxel_band"])
        with pytest.raises(ModelFileError, match=field.replace(".", r"\.")):
            load_decoder(_put(tmp_path / "bad.msgpack", bad))
    bad = _doc(path)
    bad["state"]["unmix_"] = None
    with pytest.raises(ModelFileError, match=r"state\.domain_\.band: needs state\.unmix_"):
        load_decoder(_put(tmp_path / "bad.msgpack", bad))


@pytest.fixture(scope="module")
def lm_xyz(tmp_path_factory: pytest.TempPathFactory, synth: Any) -> Path:
    """lm-mlp in 3-axis mode, saved (version 4: the checks of the whole patch)."""
    r, f = synth(300, seed=74, pillars=3, fz_max=3.0)
    path = tmp_path_factory.mktemp("xyz") / "lm-mlp.msgpack"
    create_decoder("lm-mlp", max_epochs=30).fit(r, f).save(path)
    return path


def test_the_patch_checks_round_trip_and_are_checked(lm_xyz: Path, synth: Any,
                                                     tmp_path: Path) -> None:
    doc = _doc(lm_xyz)
    assert set(doc["state"]["domain_"]) == {"inputs", "outputs", "pattern", "departure"}
    domain = doc["meta"]["domain"]
    assert domain["departure_check"] == "validation rows" and domain["exchangeable_ratio"] < 2
    r, _ = synth(60, seed=75, pillars=3, fz_max=5.0)
    out = load_decoder(lm_xyz).decode(r)
    assert (out.reason == Reason.EXTRAPOLATED).any()
    again = load_decoder(_put(tmp_path / "copy.msgpack", doc))
    np.testing.assert_array_equal(again.decode(r).reason, out.reason)
    for part, damage, field in (
            ("pattern", lambda b: b.__setitem__("limit", 0.0), "pattern.limit"),
            ("pattern", lambda b: b.__setitem__("limit", True), "pattern.limit"),
            ("pattern", lambda b: b.__setitem__("whiten", b["mean"]), "pattern.whiten"),
            ("departure", lambda b: b.__setitem__("taxel_limit", -1.0), "departure.taxel_limit"),
            ("departure", lambda b: b.__setitem__("floor_N", "0.25"), "departure.floor_N"),
            ("departure", lambda b: b.__setitem__("mean", b["whiten"]), "departure.mean"),
            ("departure", lambda b: b.pop("patch_limit"), "departure"),
            ("departure", lambda b: b.__setitem__("extra", 1), "departure")):
        bad = _doc(lm_xyz)
        damage(bad["state"]["domain_"][part])
        with pytest.raises(ModelFileError, match=re.escape(f"state.domain_.{field}")):
            load_decoder(_put(tmp_path / "bad.msgpack", bad))
    bad = _doc(lm_xyz)
    bad["state"]["unmix_"] = None
    with pytest.raises(ModelFileError, match=r"state\.domain_\.pattern: needs state\.unmix_"):
        load_decoder(_put(tmp_path / "bad.msgpack", bad))


BROKEN = [
    ("lo > hi", lambda d: d["state"]["domain_"]["inputs"].__setitem__(
        "lo", d["state"]["domain_"]["inputs"]["hi"] | {"data": b"\x7f" * 8 * 9}),
     "state.domain_.inputs"),
    ("no outputs", lambda d: d["state"]["domain_"].pop("outputs"), "state.domain_"),
    ("pattern limit", lambda d: d["state"]["domain_"]["pattern"].__setitem__("limit", -1.0),
     "state.domain_.pattern.limit"),
    ("whiten shape", lambda d: d["state"]["domain_"]["departure"].__setitem__(
        "whiten", d["state"]["domain_"]["inputs"]["lo"]), "state.domain_.departure.whiten"),
    ("hidden_", lambda d: d["state"].__setitem__("hidden_", 3), "state.hidden_"),
    ("meta", lambda d: d.__setitem__("meta", 5), "meta"),
    ("extra key", lambda d: d.__setitem__("notes", {}), "unknown key"),
]


@pytest.mark.parametrize(("what", "damage", "field"), BROKEN, ids=[b[0] for b in BROKEN])
def test_corrupt_new_fields_are_refused_naming_them(saved: dict[str, Path], tmp_path: Path,
                                                    what: str, damage: Any, field: str) -> None:
    doc = _doc(saved["lm-mlp"])
    damage(doc)
    with pytest.raises(ModelFileError, match=field.replace(".", r"\.")):
        load_decoder(_put(tmp_path / "bad.msgpack", doc))


def test_hybrids_residual_switches_are_checked(saved: dict[str, Path], tmp_path: Path) -> None:
    doc = _doc(saved["hybrid"])
    doc["state"]["use_residual_"] = True
    with pytest.raises(ModelFileError, match=r"state\.use_residual_"):
        load_decoder(_put(tmp_path / "bad.msgpack", doc))
