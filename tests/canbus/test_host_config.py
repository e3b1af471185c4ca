from __future__ import annotations

from pathlib import Path

import pytest

from canbus.master.cobids import node_cob_ids, predefined_tpdo_cob_ids
from canbus.master.forcenode import force_node_cob_ids
from canbus.master.hostconfig import HostConfig, PatchConfig, load_host_config
from canbus.od import load_od
from canbus.pdo_codec import read_defaults, read_layouts
from decoder.registry import create_decoder
from sim import Simulator, load_scene
from skin.constants import SensorConstants
from skin.errors import ConfigError

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "host.toml"


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "host.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _error(tmp_path: Path, text: str) -> str:
    """The one-line error of the config ``text``, without the file's name it starts with."""
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_host_config(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: ")
    return message.removeprefix(f"{path}: ")


def test_the_documented_example_loads_with_its_values() -> None:
    config = load_host_config(EXAMPLE)
    assert config.sync_period_ms == 10.0 and config.sync_window_ms == 8.0
    assert config.other_nodes == (32, 33)
    assert config.drift is not None and config.drift.time_constant_s == 30.0
    assert [(p.node_id, p.decoder, p.mode, p.force_node) for p in config.patches] == [
        (1, "analytic", "xyz", 65), (2, "analytic", "z", 66), (3, "analytic", "xyz", 100)]
    assert config.patches[2].force_cob_ids == tuple(range(0x1E0, 0x1E7))


def test_defaults_fill_a_minimal_config(tmp_path: Path) -> None:
    config = load_host_config(_write(tmp_path, "[[patches]]\nnode_id = 5\n"))
    assert config.patches == (PatchConfig(5, "analytic", None, "xyz", 69, None, bus="default",
                                          force_bus="default"),)
    assert config.sync_window_ms == pytest.approx(0.8 * config.sync_period_ms)
    assert config.drift is None and config.scan


@pytest.mark.parametrize(("text", "expected"), [
    ("[[patches]]\n", "patches[0].node_id: missing"),
    ("[[patches]]\nnode_id = 0\n", "patches[0].node_id: must be a node-ID in 1..127"),
    ("[[patches]]\nnode_id = 1\ncolour = 3\n", "patches[0].colour: unknown key"),
    ("[[patches]]\nnode_id = 1\nmode = 'xy'\n", "patches[0].mode: must be one of z, xyz"),
    ("[[patches]]\nnode_id = 1\ndecoder = 'magic'\n", "patches[0].decoder: unknown decoder"),
    ("[[patches]]\nnode_id = 1\ndecoder = 'deconv'\n", "patches[0].model: decoder 'deconv' "
     "must be fitted"),
    ("[[patches]]\nnode_id = 1\nmodel = 'm.msgpack'\n", "patches[0].model: no such file"),
    ("[[patches]]\nnode_id = '1'\n",
     "patches[0].node_id: must be a node-ID in 1..127, got a string '1'"),
    ("[[patches]]\nnode_id = 1\nforce_node = 200\n", "patches[0].force_node: must be a node-ID"),
    ("[[patches]]\nnode_id = 1\nforce_cob_ids = [0x1E0]\n",
     "patches[0].force_cob_ids: must list 7 COB-IDs"),
    ("[[patches]]\nnode_id = 1\nforce_cob_ids = [0x1E0, 0x1E1, 0x1E2, 0x1E3, 0x1E4, 0x1E5, "
     "0x701]\n", "patches[0].force_cob_ids[6]: 0x701 is not an 11-bit COB-ID a PDO may use"),
    ("[host]\nsync_period_ms = 0\n[[patches]]\nnode_id = 1\n", "host.sync_period_ms: must be > 0"),
    ("[host]\nsync_period_ms = 10\nsync_window_ms = 12\n[[patches]]\nnode_id = 1\n",
     "host.sync_window_ms: 12 is longer than the SYNC period 10"),
    ("[host]\nheartbeat_ms = 70000\n[[patches]]\nnode_id = 1\n",
     "host.heartbeat_ms: must be in 1..65535, got 70000"),
    ("[host]\nscan = 1\n[[patches]]\nnode_id = 1\n",
     "host.scan: must be true or false, got an integer 1"),
    ("[host]\nlisten_only = 'yes'\n[[patches]]\nnode_id = 1\n",
     "host.listen_only: must be true or false, got a string 'yes'"),
    ("[[patches]]\nnode_id = 1\nconstants = 3\n",
     "patches[0].constants: must be a table of sensor constants"),
    ("[[patches]]\nnode_id = 1\nconstants = { adc_bits = 12 }\n",
     "patches[0].constants.adc_bits: unknown key; known: area_m2, "),
    ("[[patches]]\nnode_id = 1\nconstants = { resistivity_ohm_m = -0.4 }\n",
     "patches[0].constants.resistivity_ohm_m: must be in 1e-05..1000, got -0.4"),
    ("[[patches]]\nnode_id = 1\nconstants = { youngs_modulus_pa = 4294967295 }\n",
     "patches[0].constants.youngs_modulus_pa: must be in 10000..1e+09, got 4294967295"),
    ("[[patches]]\nnode_id = 1\nconstants = { resistivity_ohm_m = 1000, area_m2 = 1e-8 }\n",
     "patches[0].constants.resistivity_ohm_m: 1000.0 Ω·m over pillars of 0.01 m and 1e-08 m² "
     "gives R0 1e+09..1.41421e+09 Ω, outside 0.1..1e+06 Ω"),
    ("[[patches]]\nnode_id = 1\n[patches.constants]\nmax_strain = 'a lot'\n",
     "patches[0].constants.max_strain: must be a number, got a string 'a lot'"),
    ("[[patches]]\nnode_id = 1\nr0_ohm = 1000\n",
     "patches[0].r0_ohm: must be an array, got an integer 1000"),
    ("[[patches]]\nnode_id = 1\nr0_ohm = [1000.0, 1414.2]\n",
     "patches[0].r0_ohm: must list 27 values (taxel 0 z, x, y, taxel 1 ...) or 3"),
    ("[[patches]]\nnode_id = 1\nr0_ohm = [1000.0, 0, 1414.2]\n",
     "patches[0].r0_ohm[1]: must be in 0.1..1e+06, got 0"),
    ("[[patches]]\nnode_id = 1\nr0_ohm = [1000.0, 4294967.295, 1414.2]\n",
     "patches[0].r0_ohm[1]: must be in 0.1..1e+06, got 4294967.295"),
    ("[[patches]]\nnode_id = 1\nr0_ohm = [1000.0, nan, 1414.2]\n",
     "patches[0].r0_ohm[1]: must be a finite number"),
    ("[host]\nother_nodes = [1, 'x']\n[[patches]]\nnode_id = 2\n",
     "host.other_nodes[1]: must be a node-ID in 1..127, got a string 'x'"),
    ("[drift]\ntime_constant_s = -1\n[[patches]]\nnode_id = 1\n",
     "drift.time_constant_s: must be > 0 and <= 1e+06, got -1"),
    ("[hosts]\n[[patches]]\nnode_id = 1\n", "hosts: unknown key"),
    ("[host]\n", "patches: missing"),
    ("[[patches]]\nnode_id = 1\n[[patches\n", "config: "),
])
def test_a_bad_config_fails_with_one_line_naming_the_field(tmp_path: Path, text: str,
                                                           expected: str) -> None:
    assert _error(tmp_path, text).startswith(expected)


def test_listen_only_and_what_the_patches_report_are_read(tmp_path: Path) -> None:
    text = ("[host]\nlisten_only = true\n[[patches]]\nnode_id = 1\nr0_ohm = [1001, 1415.5, "
            "1413]\n[patches.constants]\nresistivity_ohm_m = 0.41\nresistance_lsb_ohm = "
            "0.02\n[[patches]]\nnode_id = 2\nr0_ohm = [" + ", ".join(["1000.5"] * 27) + "]\n")
    config = load_host_config(_write(tmp_path, text))
    assert config.listen_only
    first, second = config.patches
    assert first.constants == SensorConstants(resistivity_ohm_m=0.41, resistance_lsb_ohm=0.02)
    assert first.r0_ohm == (1001.0, 1415.5, 1413.0) and second.r0_ohm == (1000.5,) * 27
    assert second.constants is None
    assert not load_host_config(_write(tmp_path, "[[patches]]\nnode_id = 1\n")).listen_only
    with pytest.raises(ConfigError, match=r"^patches\[0\]\.r0_ohm: must list 27"):
        HostConfig(patches=(PatchConfig(1, r0_ohm=(1.0,) * 9),)).check()


def test_a_missing_config_file_names_it(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"^config: no such file .*nope.toml"):
        load_host_config(tmp_path / "nope.toml")


@pytest.mark.parametrize(("text", "expected"), [
    # a force node at another patch's node-ID
    ("[[patches]]\nnode_id = 1\nforce_node = 2\n[[patches]]\nnode_id = 2\n",
     "patches[1].node_id: node-ID 2 is also patches[0].force_node"),
    # two patches, one node-ID
    ("[[patches]]\nnode_id = 3\n[[patches]]\nnode_id = 3\n",
     "patches[1].node_id: node-ID 3 is also patches[0].node_id"),
    # an arm drive at the default force node-ID of patch 1
    ("[host]\nother_nodes = [65]\n[[patches]]\nnode_id = 1\n",
     "patches[0].force_node: node-ID 65 is also host.other_nodes[0]"),
    # a force TPDO on patch 2's TPDO 1
    ("[[patches]]\nnode_id = 1\nforce_cob_ids = [0x182, 0x1E1, 0x1E2, 0x1E3, 0x1E4, 0x1E5, "
     "0x1E6]\n[[patches]]\nnode_id = 2\n",
     "patches[0].force_cob_ids[0]: 0x182 (patches[0].force_node TPDO 1) is also "
     "patches[1].node_id TPDO 1"),
    # a force TPDO on the RPDO 1 of an arm drive
    ("[host]\nother_nodes = [32]\n[[patches]]\nnode_id = 1\nforce_cob_ids = [0x220, 0x1E1, "
     "0x1E2, 0x1E3, 0x1E4, 0x1E5, 0x1E6]\n",
     "patches[0].force_cob_ids[0]: 0x220 (patches[0].force_node TPDO 1) is also "
     "host.other_nodes[0] RPDO 1"),
    # two force nodes on one COB-ID
    ("[[patches]]\nnode_id = 1\nforce_cob_ids = [0x1E0, 0x1E1, 0x1E2, 0x1E3, 0x1E4, 0x1E5, "
     "0x1E6]\n[[patches]]\nnode_id = 2\nforce_cob_ids = [0x1F0, 0x1F1, 0x1E2, 0x1F3, 0x1F4, "
     "0x1F5, 0x1F6]\n", "patches[1].force_cob_ids[2]: 0x1E2"),
    # a force TPDO on the EMCY of a patch
    ("[[patches]]\nnode_id = 1\nforce_cob_ids = [0x082, 0x1E1, 0x1E2, 0x1E3, 0x1E4, 0x1E5, "
     "0x1E6]\n[[patches]]\nnode_id = 2\n", "patches[0].force_cob_ids[0]: 0x082"),
])
def test_a_cob_id_collision_in_the_config_is_refused(tmp_path: Path, text: str,
                                                     expected: str) -> None:
    assert _error(tmp_path, text).startswith(expected)


def test_a_config_built_in_code_is_checked_the_same_way() -> None:
    clash = HostConfig(patches=(PatchConfig(1, force_node=2), PatchConfig(2)))
    with pytest.raises(ConfigError, match=r"^patches\[1\]\.node_id: node-ID 2"):
        clash.check()
    assert HostConfig(patches=(PatchConfig(1),)).check().patches[0].decoder == "analytic"


def test_predefined_identifiers_are_the_eds_defaults() -> None:
    for node_id in (1, 64, 127):
        for eds in ("skin-patch", "skin-forces"):
            layouts = read_layouts(read_defaults(load_od(eds, node_id)), 7)
            assert predefined_tpdo_cob_ids(node_id) == tuple(x.cob_id for x in layouts)
        own = set(node_cob_ids(node_id)) | set(predefined_tpdo_cob_ids(node_id))
        assert force_node_cob_ids(node_id) <= own  # the config checks all the force node uses


@pytest.fixture(scope="module")
def z_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    frame = Simulator(load_scene("paper")).run(200)
    model = create_decoder("deconv").fit(frame.resistance_ohm[:, 0], frame.force_N[:, 0])
    path = tmp_path_factory.mktemp("models") / "deconv-z.msgpack"
    model.save(path)
    return path


def test_a_model_file_names_its_decoder_and_must_fit_the_mode(tmp_path: Path,
                                                              z_model: Path) -> None:
    ok = _write(tmp_path, f"[[patches]]\nnode_id = 1\nmode = 'z'\nmodel = '{z_model.name}'\n")
    (tmp_path / z_model.name).write_bytes(z_model.read_bytes())  # relative to the config
    patch = load_host_config(ok).patches[0]
    assert (patch.decoder, patch.model) == ("deconv", tmp_path / z_model.name)
    assert _error(tmp_path, f"[[patches]]\nnode_id = 1\nmodel = '{z_model}'\n").startswith(
        "patches[0].mode: 'xyz' reads 3 pillar(s) but the model was fitted on 1")
    assert _error(tmp_path, f"[[patches]]\nnode_id = 1\nmode = 'z'\ndecoder = 'hybrid'\n"
                            f"model = '{z_model}'\n").startswith(
        "patches[0].decoder: 'hybrid' but the model file holds a 'deconv' model")
    broken = Path(__file__).resolve().parents[1] / "files" / "model_truncated.msgpack"
    assert _error(tmp_path, f"[[patches]]\nnode_id = 1\nmodel = '{broken}'\n").startswith(
        "patches[0].model: ")


def test_the_check_knows_a_decoder_needs_fitting_without_decoding(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from decoder.analytic import AnalyticDecoder
    from decoder.deconv import DeconvDecoder

    def decode(self: object, resistance_ohm: object) -> None:
        raise AssertionError("the config check decoded")

    for cls in (AnalyticDecoder, DeconvDecoder):
        monkeypatch.setattr(cls, "decode", decode)
    assert HostConfig(patches=(PatchConfig(1, decoder="analytic"),)).check().checked
    with pytest.raises(ConfigError, match=r"patches\[0\]\.model: decoder 'deconv' must be fitted"):
        HostConfig(patches=(PatchConfig(1, decoder="deconv"),)).check()
