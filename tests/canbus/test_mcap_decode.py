"""``skin decode REC -o forces.mcap``: a recording in any of the four formats turned into an
MCAP file holding the same forces, bit for bit, as ``-o forces.npz``; its frames decode
again (``skin decode forces.mcap``) to the same forces; the contact summary is on its
wrench, CoP and state topics, as the independent ``mcap`` reader decodes them."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("mcap_ros2", reason="the mcap extra is not installed")


from canbus.offline.mcap import read_forces
from canbus.tools.recorder import Recorder
from canbus.tools.recording import Recording
from skin.cli import main
from tests.canbus.mcap_independent import decoded
from tests.support.rigs.recording import record

FORMATS = (".log", ".asc", ".blf", ".pcap")


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("mcap-decode")
    log, _truth = record(folder, "mcap-decode", cycles=30, nodes=(1, 2))
    out = {".log": log}
    for suffix in FORMATS[1:]:
        recorder = Recorder(folder / f"run{suffix}")
        with Recording(log) as frames:
            for msg in frames:
                recorder.on_message_received(msg)
        recorder.stop()
        out[suffix] = folder / f"run{suffix}"
    (folder / "host.toml").write_text("[host]\nsync_period_ms = 10.0\nheartbeat_ms = 100\n"
                                      "[[patches]]\nnode_id = 1\nposition_m = [0.0, 0.1]\n"
                                      "[[patches]]\nnode_id = 2\n", encoding="utf-8")
    return out


def _decode(recording: Path, output: Path) -> None:
    assert main(["decode", str(recording), "--config", str(recording.parent / "host.toml"),
                 "-o", str(output)]) == 0


def _assert_as_npz(mcap: Path, npz: Path) -> None:
    saved = np.load(npz)
    back = list(read_forces(str(mcap)))
    assert len(back) == len(saved["cycle"]) > 40
    assert np.array([f.force_N for f in back]).tobytes() == saved["force_N"].tobytes()
    assert [f.valid.tolist() for f in back] == saved["valid"].tolist()
    assert [f.reason.tolist() for f in back] == saved["reason"].tolist()
    assert [(f.cycle, f.patch, f.force_node, f.sync_counter, f.complete) for f in back] == \
        list(zip(saved["cycle"].tolist(), saved["patch"].tolist(),
                 saved["force_node"].tolist(), saved["sync_counter"].tolist(),
                 saved["complete"].tolist(), strict=True))
    assert np.array([f.timestamp for f in back]).tobytes() == saved["time_s"].tobytes()


@pytest.mark.parametrize("suffix", FORMATS)
def test_decode_to_mcap_gives_the_forces_of_decode_to_npz(
        recordings: dict[str, Path], tmp_path: Path, suffix: str) -> None:
    source = recordings[suffix]
    _decode(source, tmp_path / "forces.npz")
    _decode(source, tmp_path / "forces.mcap")
    _assert_as_npz(tmp_path / "forces.mcap", tmp_path / "forces.npz")
    with Recording(source) as a, Recording(tmp_path / "forces.mcap") as b:
        assert [(m.arbitration_id, bytes(m.data)) for m in a] == \
            [(m.arbitration_id, bytes(m.data)) for m in b]
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_an_mcap_decodes_again_and_its_contact_topics_hold_the_summary(
        recordings: dict[str, Path], tmp_path: Path) -> None:
    first = tmp_path / "forces.mcap"
    _decode(recordings[".log"], first)
    (tmp_path / "host.toml").write_bytes((recordings[".log"].parent / "host.toml").read_bytes())
    again = tmp_path / "again.npz"
    _decode(first, again)  # the MCAP's own frames, through the decoders again
    _assert_as_npz(first, again)
    saved = np.load(again)
    by_topic: dict[str, list[Any]] = {}
    for topic, message in decoded(first):
        by_topic.setdefault(topic, []).append(message)
    order = np.lexsort((saved["patch"], saved["time_s"]))  # the reader's order: log time
    for patch in (1, 2):
        rows = [k for k in order if saved["patch"][k] == patch]
        wrenches = by_topic[f"/skin/patch_{patch}/wrench"]
        force = [[w.wrench.force.x, w.wrench.force.y, w.wrench.force.z]
                 for w in wrenches]
        assert np.array(force).tobytes() == saved["contact_force_N"][rows].tobytes()
        states = [s.data for s in by_topic[f"/skin/patch_{patch}/contact_state"]]
        assert states == saved["contact_state"][rows].tolist()
        cops = by_topic.get(f"/skin/patch_{patch}/cop", [])
        assert len(cops) == int(saved["cop_defined"][rows].sum())
    tf = by_topic["/tf_static"][0]
    placed = {t.child_frame_id: t.transform.translation.y for t in tf.transforms}
    assert placed == {"skin_patch_1": 0.1, "skin_patch_2": 0.0}
