"""Scene parsing: shipped scenes load, and every bad input names its field."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sim import Simulator, load_scene, scene_from_dict, shipped_scenes
from skin.constants import DEFAULT_CONSTANTS
from skin.errors import ConfigError
from skin.tripod import resistance_from_force

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels

FILES = Path(__file__).parents[1] / "files"
BASE: dict[str, Any] = {
    "scene": {"name": "t", "mode": "xyz"},
    "patches": [{"node_id": 1}, {"node_id": 2}],
    "loads": [{"kind": "uniform_random", "fz_max_N": 4.0}],
    "effects": {"elastic_crosstalk": {}},
}


def with_change(path: tuple[Any, ...], value: Any) -> dict[str, Any]:
    data = copy.deepcopy(BASE)
    node = data
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return data


def test_shipped_scenes_load_and_run() -> None:
    names = shipped_scenes()
    for required in ("paper", "paper-noisy", "indenter", "slide", "grasp", "idle", "passive",
                     "hard", "skin64"):
        assert required in names
    for name in names:
        scene = load_scene(name)
        frame = Simulator(scene).run(3)
        assert frame.resistance_ohm.shape == (3, len(scene.patches), 9, scene.pillars)


def test_paper_scene_is_the_papers_protocol() -> None:
    """One patch, z-only, independent Fz ~ U[0, 5] N, crosstalk and nothing else: the
    paper's samples came from a finite-element model, without read noise."""
    scene = load_scene("paper")
    assert scene.mode == "z" and scene.node_ids == (1,)
    assert scene.listed_effects() == ["elastic_crosstalk"]
    (load,) = scene.loads
    assert load.kind == "uniform_random"
    assert (load.params.fz_min_N, load.params.fz_max_N, load.params.shear_max_N) == (0, 5, 0)
    frame = Simulator(scene).run(200)
    exact = resistance_from_force(scene.crosstalk_matrix() @ frame.force_N)
    np.testing.assert_allclose(frame.resistance_ohm, exact[..., :1], rtol=1e-12)


def test_paper_noisy_is_paper_with_read_noise_and_the_adc() -> None:
    paper, noisy = load_scene("paper").to_dict(), load_scene("paper-noisy").to_dict()
    assert noisy["effects"] == {**paper["effects"], "noise": {"sigma_rel": 0.0005}}
    assert (noisy["patches"], noisy["loads"]) == (paper["patches"], paper["loads"])
    frame = Simulator(load_scene("paper-noisy")).run(50)
    lsb = DEFAULT_CONSTANTS.resistance_lsb_ohm
    np.testing.assert_allclose(frame.resistance_ohm / lsb, np.rint(frame.resistance_ohm / lsb),
                               atol=1e-9)


def test_to_dict_round_trips() -> None:
    for name in shipped_scenes():
        scene = load_scene(name)
        assert scene_from_dict(scene.to_dict()) == scene


def test_crosstalk_matrix_identity_without_effect() -> None:
    data = with_change(("effects",), {})
    np.testing.assert_array_equal(scene_from_dict(data).crosstalk_matrix(), np.eye(9))


@pytest.mark.parametrize(
    ("path", "value", "field"),
    [
        (("loads", 0, "kind"), "foo", "loads[0].kind"),
        (("loads", 0, "radius_mm"), 1.0, "loads[0].radius_mm"),
        (("loads", 0, "fz_max_N"), "five", "loads[0].fz_max_N"),
        (("loads", 0, "patches"), [3], "loads[0].patches[0]"),
        (("effects", "wobble"), {}, "effects.wobble"),
        (("effects", "elastic_crosstalk", "coupling"), -0.1, "effects.elastic_crosstalk.coupling"),
        (("effects", "readout"), {"kind": "psychic"}, "effects.readout.kind"),
        (("effects", "noise"), {"sigma": 1.0}, "effects.noise.sigma"),
        (("scene", "mode"), "xy", "scene.mode"),
        (("scene", "rate_hz"), 0.0, "scene.rate_hz"),
        (("scene", "colour"), "red", "scene.colour"),
        (("patches", 1, "node_id"), 128, "patches[1].node_id"),
        (("patches", 1, "position_m"), [0.0], "patches[1].position_m"),
        (("extra",), {}, "extra"),
        (("effects", "faults"), {"pillars": [{"node_id": 9, "taxel": 0}]},
         "effects.faults.pillars[0].node_id"),
        (("effects", "faults"), {"pillars": [{"node_id": 1, "taxel": 9}]},
         "effects.faults.pillars[0].taxel"),
        (("effects", "faults"), {"pillars": [{"node_id": 1, "taxel": 0, "kind": "melted"}]},
         "effects.faults.pillars[0].kind"),
    ],
)
def test_bad_field_is_named(path: tuple[Any, ...], value: Any, field: str) -> None:
    with pytest.raises(ConfigError) as info:
        scene_from_dict(with_change(path, value))
    assert info.value.field == field
    assert str(info.value).startswith(f"{field}: ")


def test_unknown_load_lists_known() -> None:
    with pytest.raises(ConfigError, match=r"sim_unknown_load\.toml: loads\[0\]\.kind: unknown "
                       r"load 'foo'; known: uniform_random, indenter, slide, grasp, idle, "
                       r"stick_slip$"):
        load_scene(FILES / "sim_unknown_load.toml")


def test_fault_on_unread_pillar_in_z_mode() -> None:
    data = with_change(("scene", "mode"), "z")
    data["effects"]["faults"] = {"pillars": [{"node_id": 1, "taxel": 0, "pillar": "x"}]}
    with pytest.raises(ConfigError, match=r"pillars\[0\]\.pillar: pillar 'x' is not read"):
        scene_from_dict(data)


def test_malformed_toml() -> None:
    with pytest.raises(ConfigError, match=r"sim_bad_syntax\.toml: scene: not valid TOML: "):
        load_scene(FILES / "sim_bad_syntax.toml")


def test_unknown_scene_name_and_missing_file() -> None:
    with pytest.raises(ConfigError, match=r"unknown scene 'nope'; shipped: .*paper"):
        load_scene("nope")
    with pytest.raises(ConfigError, match="no scene file"):
        load_scene(FILES / "absent.toml")


def test_overstrain_names_the_load_field() -> None:
    scene = load_scene(FILES / "sim_overstrain.toml")
    with pytest.raises(ConfigError, match=r"sim_overstrain\.toml: loads\[0\]\.fz_max_N: 20 "
                       r"strains a pillar past 20 %"):
        Simulator(scene)


def test_overstrain_by_shear_names_shear_field() -> None:
    data = with_change(("loads", 0, "shear_max_N"), 30.0)
    with pytest.raises(ConfigError) as info:
        Simulator(scene_from_dict(data))
    assert info.value.field == "loads[0].shear_max_N"
    assert isinstance(info.value.__cause__, Exception)


def test_a_scene_on_n_patches_puts_every_load_on_every_patch() -> None:
    from sim import on_patches

    hard = load_scene("hard")
    assert any(p["node_id"] == 2 for p in hard.to_dict()["effects"]["faults"]["pillars"])
    one = on_patches(hard, 1, spacing_m=0.1)
    assert one.node_ids == (1,) and all(load.patches == (1,) for load in one.loads)
    assert {p["node_id"] for p in one.to_dict()["effects"]["faults"]["pillars"]} == {1}
    four = on_patches(hard, 4, spacing_m=0.1)
    assert [tuple(p.position_m) for p in four.patches] == [(0.0, 0.0), (0.1, 0.0), (0.0, 0.1),
                                                           (0.1, 0.1)]
    assert all(load.patches == (1, 2, 3, 4) for load in four.loads)
    nine = on_patches(load_scene("indenter"), 9)
    assert nine.node_ids == tuple(range(1, 10)) and max(p.position_m[1] for p in nine.patches) \
        == pytest.approx(0.1)
    frame = Simulator(nine).run(300)
    assert frame.resistance_ohm.shape[1] == 9
    assert (frame.force_N[..., 2].max(axis=(0, 2)) > 0.1).all()  # every patch is pressed
    with pytest.raises(ConfigError, match="patches"):
        on_patches(hard, 128)
