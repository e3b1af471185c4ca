"""Scenes and host configs damaged on purpose: one line naming the file (and the field),
nothing written, the input untouched."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from canbus.master.hostconfig import load_host_config
from skin.errors import ConfigError
from tests.inputs.conftest import examples
from tests.inputs.hostile import (
    answered,
    fingerprint,
    message_of,
    mutate_bytes,
    mutate_document,
    refused,
    run,
    to_toml,
)

ROOT = Path(__file__).resolve().parents[2]
SCENES = sorted((ROOT / "sim" / "scenes").glob("*.toml"))
CONFIG = ROOT / "examples" / "host.toml"


def _scene_run(folder: Path, scene: Path) -> None:
    before = fingerprint(folder)
    out = folder / "out" / "d.npz"
    out.parent.mkdir(exist_ok=True)
    result = run("sim", "dataset", scene, "-n", "3", "-o", out)
    answered(result)
    if result.code:
        assert str(scene) in result.lines[0]
        assert not out.exists()
    else:
        out.unlink()
    assert fingerprint(folder) == before


@examples(40)
@given(data=st.data(), source=st.sampled_from(SCENES))
def test_a_scene_damaged_in_its_values(tmp_path_factory: pytest.TempPathFactory,
                                       data: st.DataObject, source: Path) -> None:
    folder = tmp_path_factory.mktemp("scene")
    doc = mutate_document(tomllib.loads(source.read_text()), data.draw)
    scene = folder / "scene.toml"
    scene.write_text(to_toml(doc))
    _scene_run(folder, scene)


@examples(25)
@given(data=st.data(), source=st.sampled_from(SCENES))
def test_a_scene_damaged_in_its_bytes(tmp_path_factory: pytest.TempPathFactory,
                                      data: st.DataObject, source: Path) -> None:
    folder = tmp_path_factory.mktemp("scene")
    scene = folder / "scene.toml"
    scene.write_bytes(mutate_bytes(source.read_bytes(), data.draw))
    _scene_run(folder, scene)


PAPER = (ROOT / "sim" / "scenes" / "paper.toml").read_bytes()


@pytest.mark.parametrize(("content", "field"), [
    (PAPER.replace(b'name = "paper"', b'name = "\xff"'), "not UTF-8"),
    (PAPER.replace(b"rate_hz = 100.0", b"rate_hz = " + b"[" * 5000 + b"]" * 5000), "nested"),
    (PAPER.replace(b"position_m = [0.0, 0.0]", b"position_m = [nan, 0]"),
     "patches[0].position_m[0]"),
    (PAPER.replace(b"coupling = 0.05", b"coupling = 1e300"), "effects.elastic_crosstalk.coupling"),
    (PAPER.replace(b"fz_max_N = 5.0", b"fz_max_N = 5.0\npatches = [true]"),
     "loads[0].patches[0]: must be a node-ID in 1..127, got a boolean"),
])
def test_the_issues_scene_examples(tmp_path: Path, content: bytes, field: str) -> None:
    assert content != PAPER
    scene = tmp_path / "s.toml"
    scene.write_bytes(content)
    result = run("sim", "dataset", scene, "-n", "3", "-o", tmp_path / "d.npz")
    refused(result)
    assert str(scene) in result.lines[0] and field in result.lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.toml"]


def _config_check(path: Path) -> None:
    message = message_of(lambda: load_host_config(path), ConfigError)
    assert message is None or ("\n" not in message and message.startswith(str(path))), message


@examples(60)
@given(data=st.data())
def test_a_host_config_damaged_in_its_values(tmp_path_factory: pytest.TempPathFactory,
                                             data: st.DataObject) -> None:
    folder = tmp_path_factory.mktemp("config")
    config = folder / "host.toml"
    config.write_text(to_toml(mutate_document(tomllib.loads(CONFIG.read_text()), data.draw)))
    before = fingerprint(folder)
    _config_check(config)
    assert fingerprint(folder) == before


@examples(30)
@given(data=st.data())
def test_a_host_config_damaged_in_its_bytes(tmp_path_factory: pytest.TempPathFactory,
                                            data: st.DataObject) -> None:
    folder = tmp_path_factory.mktemp("config")
    config = folder / "host.toml"
    config.write_bytes(mutate_bytes(CONFIG.read_bytes(), data.draw))
    _config_check(config)


@examples(4)
@given(data=st.data())
def test_skin_run_on_a_damaged_config(tmp_path_factory: pytest.TempPathFactory,
                                      data: st.DataObject) -> None:
    folder = tmp_path_factory.mktemp("config")
    config = folder / "host.toml"
    doc = mutate_document(tomllib.loads(CONFIG.read_text()), data.draw)
    config.write_text(to_toml(doc))
    try:
        load_host_config(config)
    except ConfigError:
        result = run("run", config, "-i", "virtual", "--seconds", "0.01")
        refused(result)
        assert str(config) in result.lines[0]


def test_every_ranged_field_is_in_the_table_of_docs_cli() -> None:
    from sim.effects import EFFECT_PARAMS
    from sim.effects.faults import FaultSpec
    from sim.loads import LOAD_PARAMS
    from sim.scene import _Header

    table = (ROOT / "docs" / "cli.md").read_text()
    classes = [*LOAD_PARAMS.values(), *EFFECT_PARAMS.values(), FaultSpec, _Header]
    missing = [f"{cls.__name__}.{name}" for cls in classes
               for name in getattr(cls, "RANGES", {}) if f"`{name}`" not in table]
    assert missing == []
