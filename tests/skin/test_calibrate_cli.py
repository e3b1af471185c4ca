"""``skin calibrate``: the model and its report, the host-config snippet, ``--check`` and its
exit status, and the rest values written to a patch by SDO, which an active host reads."""

from __future__ import annotations

import json
import struct
import tomllib
from pathlib import Path
from types import SimpleNamespace

import can
import canopen
import numpy as np
import pytest

from canbus.device.patch_server import PatchServer
from canbus.device.source import ArraySource
from canbus.master.host import HostManager
from canbus.master.hostconfig import HostConfig, PatchConfig, host_config_from_dict
from decoder.modelfile import read_model
from decoder.registry import load_decoder
from decoder.tare import nominal_r0, normalise
from sim import generate_dataset, load_scene
from skin.cli import main
from skin.constants import DEFAULT_CONSTANTS
from skin.dataset import Dataset, read_dataset, write_dataset
from skin.errors import ConfigError
from tests.support.rigs.recording import scene

FAST = ["--decoders", "analytic", "deconv"]


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two datasets of the calibration scene, one of the plain indenter, and a model."""
    path = tmp_path_factory.mktemp("calibrate")
    write_dataset(path / "d1.npz", generate_dataset(load_scene("calibration"), 300, 1))
    write_dataset(path / "d2.npz", generate_dataset(load_scene("calibration"), 300, 2))
    write_dataset(path / "indenter.npz", generate_dataset(load_scene("indenter"), 300, 3))
    assert main(["calibrate", str(path / "d1.npz"), "-o", str(path / "m.msgpack"), *FAST,
                 "--report", str(path / "r.json"), "--json", str(path / "j.json"),
                 "--config-snippet", str(path / "patch.toml")]) == 0
    return path


def test_the_model_carries_its_report(folder: Path) -> None:
    report, summary = (json.loads((folder / n).read_text()) for n in ("r.json", "j.json"))
    for doc in (report, summary):
        assert doc["decoder"] == "deconv" and doc["hidden"] is None
        assert 0 < doc["heldout_floored_pct"] < 10
        assert doc["tare"]["samples"] >= 10 and doc["folds"] == 5 and doc["node_id"] == 1
    assert summary["seconds"] > 0 and len(report["candidates"]) == 2
    assert len(report["per_taxel_floored_pct"]) == 9 and set(report["rmse_axis_N"]) == \
        {"Fx", "Fy", "Fz"}
    meta = read_model(folder / "m.msgpack").meta["calibration"]
    assert meta["decoder"] == "deconv"
    assert meta["heldout_floored_pct"] == pytest.approx(report["heldout_floored_pct"])
    np.testing.assert_array_equal(meta["tare"]["rest_ohm"], report["tare"]["rest_ohm"])
    assert meta["candidates"]["names"] == "analytic deconv"
    assert read_model(folder / "m.msgpack").meta["crosstalk"]["model"] in ("kernel", "full")


def test_the_snippet_is_a_host_config_and_the_model_decodes_in_its_frame(folder: Path) -> None:
    text = (folder / "patch.toml").read_text()
    table = tomllib.loads("[host]\nlisten_only = true\n" + text)
    config = host_config_from_dict(table, base=folder)
    patch = config.patch(1)
    assert patch.decoder == "deconv" and patch.r0_ohm is not None and patch.mode == "xyz"
    report = json.loads((folder / "r.json").read_text())
    np.testing.assert_array_equal(np.reshape(patch.r0_ohm, (9, 3)), report["tare"]["rest_ohm"])
    # decoded in the host's frame, a second run of the scene is as good as held out
    ds = read_dataset(folder / "d2.npz")
    model = load_decoder(folder / "m.msgpack")
    x = normalise(ds.resistance_ohm[:, 0], np.reshape(patch.r0_ohm, (9, 3)),
                  nominal_r0(DEFAULT_CONSTANTS, 3))
    out = model.decode(x)
    from decoder.metrics import evaluate

    e = evaluate(ds.force_N[:, 0], out.force_N, out.valid, mode="xyz")
    assert e.ave_rel_err_floored_pct < 1.25 * report["heldout_floored_pct"] + 0.1


def _check(folder: Path, data: Path, capsys: pytest.CaptureFixture[str],
           lines: list[str] | None = None) -> tuple[int, dict]:
    out = folder / "check.json"
    code = main(["calibrate", "--check", str(folder / "m.msgpack"), str(data), "--json",
                 str(out)])
    if lines is not None:
        lines[:] = capsys.readouterr().out.splitlines()
    capsys.readouterr()
    return code, json.loads(out.read_text())


def test_check_says_whether_the_model_still_fits(folder: Path, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    lines: list[str] = []
    code, doc = _check(folder, folder / "d2.npz", capsys, lines)
    assert code == 0 and doc["verdict"] == "fits" and doc["now"]["fits"]
    covered = doc["now"]["covered_pct"]
    assert covered == pytest.approx(100 - doc["now"]["flagged_pct"])
    assert f" over {covered:.2f} % of the taxels (its own held-out " in lines[0]
    # the rest drifted 1 % (a temperature change): a tare restores the fit
    ds = read_dataset(folder / "d2.npz")
    drifted = tmp_path / "drifted.npz"
    write_dataset(drifted, Dataset(ds.resistance_ohm * 1.01, ds.force_N, ds.meta))
    code, doc = _check(folder, drifted, capsys)
    assert code == 4 and not doc["now"]["fits"] and doc["after_tare"]["fits"]
    # another patch (the shipped crosstalk and R0): no tare helps, recalibrate
    code, doc = _check(folder, folder / "indenter.npz", capsys)
    assert code == 3 and not doc["now"]["fits"] and not doc["after_tare"]["fits"]
    assert doc["limit_pct"] == pytest.approx(1.25 * doc["own_heldout_floored_pct"] + 0.1)
    # every taxel refused (every pillar open): not a perfect score, no result, first line
    opened = tmp_path / "open.npz"
    write_dataset(opened, Dataset(np.full_like(ds.resistance_ohm, np.inf), ds.force_N, ds.meta))
    code, doc = _check(folder, opened, capsys, lines)
    assert code == 3 and doc["now"]["covered_pct"] == 0.0 and doc["now"]["floored_pct"] is None
    assert lines[0].startswith(f"{folder / 'm.msgpack'} refused every taxel of patch 1 of "
                               f"{opened} (")
    assert "no result, its error covers nothing" in lines[0]


def test_bad_use_is_one_line(folder: Path, tmp_path: Path,
                             capsys: pytest.CaptureFixture[str]) -> None:
    two = tmp_path / "two.npz"
    write_dataset(two, generate_dataset(scene("xyz", nodes=(3, 5)), 40, 1))  # type: ignore[arg-type]
    plain = tmp_path / "plain.msgpack"
    assert main(["train", "deconv", "--data", str(folder / "d1.npz"), "-o", str(plain)]) == 0
    capsys.readouterr()
    for argv, message in (
            ([str(folder / "d1.npz")], "-o: give the model file"),
            ([str(two), "-o", str(tmp_path / "m.msgpack")], "--node: " + str(two) +
             " holds patches 3, 5: name one"),
            ([str(two), "-o", str(tmp_path / "m.msgpack"), "--node", "4"], "holds no patch 4"),
            ([str(folder / "d1.npz"), "-o", str(tmp_path / "m.msgpack"), "--decoders", "x"],
             "unknown decoder 'x'"),
            (["--check", str(plain), str(folder / "d2.npz")], "has no calibration report"),
            (["--check", str(folder / "m.msgpack"), str(folder / "d2.npz"), "-o", "x"],
             "-o and --write-node do not apply")):
        assert main(["calibrate", *argv]) == 1, argv
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and message in err, err
    assert not (tmp_path / "m.msgpack").exists()


def test_write_node_sets_the_rest_an_active_host_reads(folder: Path, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str],
                                                       request: pytest.FixtureRequest) -> None:
    channel = f"calibrate-{request.node.name}"
    device = canopen.Network()
    device.NOTIFIER_CYCLE = 0.05
    device.connect(interface="virtual", channel=channel)
    rest = np.tile(DEFAULT_CONSTANTS.nominal_resistance_ohm * 1.03, (9, 1))
    bus = can.Bus(interface="virtual", channel=channel)
    try:
        with PatchServer(device, ArraySource(rest[None, None], (1,))) as server:
            assert main(["calibrate", str(folder / "d1.npz"), "-o", str(tmp_path / "m.msgpack"),
                         *FAST, "--write-node", "--store", "-i", "virtual",
                         "-c", channel]) == 0
            assert "wrote 27 rest values to patch 1's 0x2002" in capsys.readouterr().out
            saved = server.nodes[0].nv.content.objects  # 0x1010 sub 4 "save": R0 kept
            assert sorted(s for i, s in saved if i == 0x2002) == list(range(1, 28))
            report = json.loads((folder / "r.json").read_text())
            want = np.array(report["tare"]["rest_ohm"])
            store = server.nodes[0].store
            got = np.array([store.value(0x2002, s) for s in range(1, 28)]).reshape(9, 3)
            np.testing.assert_array_equal(got, np.rint(want * 1000))  # mOhm counts
            # an active host reads them when it configures the patch: its rest is the tare
            with HostManager(bus, HostConfig(patches=(PatchConfig(1),), scan_ms=50)) as host:
                assert host.wait_operational(timeout=10.0)
                baseline = host.dataplane.channel(1).baseline
                assert baseline is not None
                np.testing.assert_array_equal(baseline.baseline, want)
            raw = struct.pack("<I", 0)  # 0 mOhm: below LowLimit
            master = canopen.Network(can.Bus(interface="virtual", channel=channel))
            master.connect()
            try:
                od = server.nodes[0].store.object_dictionary
                node = master.add_node(canopen.RemoteNode(1, od))
                with pytest.raises(canopen.SdoAbortedError, match="0x06090032"):
                    node.sdo.download(0x2002, 1, raw)
                with pytest.raises(canopen.SdoAbortedError, match="0x06090031"):
                    node.sdo.download(0x2002, 1, struct.pack("<I", 0xFFFF_FFFF))  # HighLimit
            finally:
                master.disconnect()
    finally:
        device.disconnect()
        bus.shutdown()


def test_write_node_refuses_a_rest_outside_the_range_of_a_real_patch_before_writing_any(
        ) -> None:
    from skin.commands.calibrate.output import write_rest_to_node

    rest = np.tile(DEFAULT_CONSTANTS.nominal_resistance_ohm, (9, 1))
    rest[4, 2] = 2e6  # 2 MOhm: above 0x2002's HighLimit
    with pytest.raises(ConfigError, match=r"^rest 0x2002:0F: 2000000.0 Ω is outside "
                                          r".*\(0.1..1e\+06 Ω\)"):
        write_rest_to_node(SimpleNamespace(), 1, rest)  # no bus opened: nothing written
