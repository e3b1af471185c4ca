"""A dataset from a recording: each patch read by the mapping the recording shows, judged by
the host's data plane, joined to the truth; lost frames, gaps, a clock offset and faulty
taxels counted and left out, and every row the simulator's own step, bit for bit."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import can
import numpy as np
import pytest

from canbus.offline.dataset import JoinChoice, dataset_from_recording
from canbus.offline.recorded import read_patch_samples
from decoder.reasons import Reason
from skin.cli import main
from skin.dataset import read_dataset
from skin.errors import RecordingError
from skin.reference import ReferenceWriter, read_reference
from tests.support.rigs.recording import assert_rows_are_steps, record, rewrite, scene

SDO = range(0x580, 0x680)
PATCH_TPDOS = {0x181, 0x281, 0x381, 0x481, 0x201, 0x301, 0x401}


@dataclass
class Run:
    log: Path
    truth: Path


@pytest.fixture(scope="module")
def xyz(tmp_path_factory: pytest.TempPathFactory) -> Run:
    folder = tmp_path_factory.mktemp("xyz")
    return Run(*record(folder, "recorded-xyz", cycles=80, seed=3))


@pytest.fixture(scope="module")
def z(tmp_path_factory: pytest.TempPathFactory) -> Run:
    folder = tmp_path_factory.mktemp("z")
    return Run(*record(folder, "recorded-z", mode="z", cycles=40, seed=4))


def test_every_row_is_the_simulators_step(xyz: Run) -> None:
    made = dataset_from_recording(xyz.log, xyz.truth)
    ds, report = made.dataset, made.report
    patch = report["patches"]["1"]
    assert report["mapping"]["1"] == {"mapping": "xyz", "from": "sdo"}
    assert report["join"]["by"] == "sync" and report["join"]["clock_offset_estimated"]
    assert abs(report["join"]["clock_offset_ms"]) < 1.0  # one clock: the virtual bus's
    assert ds.resistance_ohm.shape == (patch["written"], 1, 9, 3) and patch["written"] >= 60
    assert assert_rows_are_steps(ds.resistance_ohm, ds.force_N, scene("xyz"), 3) > 30
    rec = patch["recording"]
    assert patch["written"] == rec["usable"] - patch["unjoined_recording"]
    assert ds.meta["node_ids"] == [1] and ds.meta["mode"] == "xyz"


def test_lost_frames_reference_gaps_and_a_clock_offset(xyz: Run, tmp_path: Path) -> None:
    lost = tmp_path / "lost.log"
    tpdo = [0]

    def keep(k: int, msg: can.Message) -> bool:  # one frame of every fifth answer
        if msg.arbitration_id != 0x381:
            return True
        tpdo[0] += 1
        return tpdo[0] % 5 != 0

    rewrite(xyz.log, lost, keep)
    ref = read_reference(xyz.truth)
    rng = np.random.default_rng(9)
    kept = rng.uniform(size=len(ref.sync)) > 0.2
    kept[20:25] = False
    offset = -5000.25  # the reference clock runs 5000.25 s ahead
    gappy = tmp_path / "gappy.csv"
    with ReferenceWriter(gappy) as writer:
        for k in np.flatnonzero(kept):
            writer.write(ref.time_s[k] - offset, int(ref.sync[k]), 1, ref.force_N[k])
    for by in ("sync", "time"):
        made = dataset_from_recording(lost, gappy, how=JoinChoice(by=by))
        patch, how = made.report["patches"]["1"], made.report["join"]
        assert how["by"] == by and how["clock_offset_estimated"]
        assert how["clock_offset_ms"] == pytest.approx(1000 * offset, abs=1.0)
        samples = made.recorded.patches[1]
        assert patch["recording"]["incomplete"] >= tpdo[0] // 5 - 2
        assert patch["reference"]["samples"] == kept.sum()
        # every reference sample answers a recorded SYNC: none is left unjoined, and each
        # joined to an incomplete answer is left out, never filled in
        assert patch["unjoined_reference"] == 0 and patch["joined"] == kept.sum()
        usable = samples.usable
        assert patch["written"] == patch["joined"] - patch["joined_but_incomplete"] \
            - patch["joined_but_unanswered"] - patch["joined_but_faulty"]
        assert patch["unjoined_recording"] >= 1 and patch["written"] < usable.sum()
        assert assert_rows_are_steps(made.dataset.resistance_ohm, made.dataset.force_N,
                                     scene("xyz"), 3) > 20


def test_z_mode_from_the_sdo_writes_and_the_mapping_option(z: Run, tmp_path: Path) -> None:
    made = dataset_from_recording(z.log, z.truth)
    assert made.report["mapping"]["1"] == {"mapping": "z", "from": "sdo"}
    assert made.dataset.resistance_ohm.shape[1:] == (1, 9, 1)
    assert assert_rows_are_steps(made.dataset.resistance_ohm, made.dataset.force_N,
                                 scene("z"), 4) > 10
    # Without the SDO writes the recording shows the EDS default (xyz): the z answers are
    # too short for it, every sample is incomplete, and nothing is written.
    no_sdo = tmp_path / "no-sdo.log"
    rewrite(z.log, no_sdo, lambda k, msg: msg.arbitration_id not in SDO)
    blind = dataset_from_recording(no_sdo, z.truth)
    assert blind.report["mapping"]["1"] == {"mapping": "xyz", "from": "eds"}
    assert blind.dataset.resistance_ohm.shape[0] == 0
    assert blind.report["patches"]["1"]["recording"]["usable"] == 0
    told = dataset_from_recording(no_sdo, z.truth, mapping="z")
    assert told.report["mapping"]["1"] == {"mapping": "z", "from": "option"}
    np.testing.assert_array_equal(told.dataset.resistance_ohm, made.dataset.resistance_ohm)


def test_a_remap_while_sending_is_refused_naming_the_frame(xyz: Run, z: Run,
                                                           tmp_path: Path) -> None:
    with can.LogReader(xyz.log) as reader:
        end = max(m.timestamp for m in reader)
    with can.LogReader(z.log) as reader:
        later = list(reader)
    shift = end + 1.0 - later[0].timestamp
    for msg in later:
        msg.timestamp += shift
    both = tmp_path / "both.log"
    rewrite(xyz.log, both, lambda k, msg: True, later)
    with pytest.raises(RecordingError, match=r"both\.log: frame \d+: patch 1 sends PDOs under "
                                             "another mapping"):
        read_patch_samples(both, (1,))


def test_faulty_taxels_are_counted_and_left_out(tmp_path: Path) -> None:
    faults = [{"node_id": 1, "taxel": 4, "pillar": "x", "kind": "open", "from_s": 0.25}]
    log, truth = record(tmp_path, "recorded-faults", cycles=50, seed=5, faults=faults)
    made = dataset_from_recording(log, truth)
    samples = made.recorded.patches[1]
    rec = made.report["patches"]["1"]["recording"]
    assert rec["with_faulty_taxels"] > 10
    assert set(rec["faulty_taxels"]) <= {"OPEN", "FAULTY"} and rec["faulty_taxels"]
    faulty = samples.complete & np.any(samples.reason != Reason.OK, axis=1)
    assert np.all(samples.reason[faulty][:, [0, 1, 2, 3, 5, 6, 7, 8]] == Reason.OK)
    assert made.report["patches"]["1"]["joined_but_faulty"] > 10
    assert np.all(np.isfinite(made.dataset.resistance_ohm))
    assert assert_rows_are_steps(made.dataset.resistance_ohm, made.dataset.force_N,
                                 scene("xyz", faults), 5) > 3


def test_can_fd_answers_and_two_patches(tmp_path: Path) -> None:
    log, truth = record(tmp_path, "recorded-fd", cycles=30, seed=6, fd=True, nodes=(1, 2))
    made = dataset_from_recording(log, truth)
    assert made.report["mapping"] == {str(n): {"mapping": "fd-xyz", "from": "sdo"}
                                      for n in (1, 2)}
    ds = made.dataset
    assert ds.resistance_ohm.shape[1:] == (2, 9, 3) and ds.meta["node_ids"] == [1, 2]
    rows = made.report["samples"]
    for node in ("1", "2"):
        p = made.report["patches"][node]
        assert p["written"] == rows
        assert p["written"] + p["left_out_other_patch"] + p["joined_but_incomplete"] + \
            p["joined_but_unanswered"] + p["joined_but_faulty"] == p["joined"]
    one = dataset_from_recording(log, truth, nodes=(2,))
    assert one.dataset.resistance_ohm.shape[1] == 1 and one.dataset.meta["node_ids"] == [2]


def test_the_command_writes_the_dataset_and_its_counts(xyz: Run, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    out, counts = tmp_path / "d.npz", tmp_path / "counts.json"
    assert main(["dataset", "from-recording", str(xyz.log), "--reference", str(xyz.truth),
                 "-o", str(out), "--json", str(counts)]) == 0
    text = capsys.readouterr().out
    assert "patch 1 (xyz mapping, from the SDO writes)" in text and f"wrote {out}" in text
    ds, report = read_dataset(out), json.loads(counts.read_text())
    assert ds.resistance_ohm.shape[0] == report["samples"] == \
        report["patches"]["1"]["written"]
    assert ds.meta["source"] == "recording" and ds.meta["recording"] == str(xyz.log)


def test_bad_input_is_one_line_naming_file_and_row_or_frame(xyz: Run, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]
                                                            ) -> None:
    bad = tmp_path / "bad.csv"
    lines = xyz.truth.read_text().splitlines()
    lines[12] = lines[12].replace(",1,", ",x,", 1)
    bad.write_text("\n".join(lines) + "\n")
    cut = tmp_path / "cut.log"
    cut.write_text(xyz.log.read_text()[:5000])
    out = tmp_path / "d.npz"
    for argv, message in (
            ([str(xyz.log), "--reference", str(bad)], f"{bad}: row 13: node_id: not a number"),
            ([str(cut), "--reference", str(xyz.truth)], f"{cut}: frame "),
            ([str(xyz.log), "--reference", str(xyz.truth), "--node", "9"],
             "--node: "),
            ([str(tmp_path / "r.txt"), "--reference", str(xyz.truth)],
             "REC: unknown recording format '.txt'")):
        assert main(["dataset", "from-recording", *argv, "-o", str(out)]) == 1
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and message in err, err
        assert not out.exists()
