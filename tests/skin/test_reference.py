"""Reference forces: the CSV/.npz format a calibration rig writes, read back exactly;
a contact point spread over the taxels; every malformed file named by file and row."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skin.constants import DEFAULT_CONSTANTS
from skin.errors import ReferenceFileError
from skin.reference import ReferenceWriter, read_reference, spread_point

PITCH = DEFAULT_CONSTANTS.taxel_pitch_m
finite = st.floats(-50.0, 50.0, allow_nan=False, allow_infinity=False)


@given(st.lists(st.tuples(st.floats(0, 1e9, allow_nan=False), st.integers(1, 240),
                          st.integers(1, 127),
                          st.lists(finite, min_size=27, max_size=27)),
                min_size=1, max_size=8, unique_by=lambda s: (s[0], s[1], s[2])))
@settings(max_examples=40, deadline=None)
def test_written_samples_read_back_exactly(tmp_path_factory: pytest.TempPathFactory,
                                           samples: list[tuple[float, int, int, list[float]]]
                                           ) -> None:
    path = tmp_path_factory.mktemp("ref") / "truth.csv"
    with ReferenceWriter(path) as writer:
        for t, sync, node, force in samples:
            writer.write(t, sync, node, np.array(force).reshape(9, 3))
    ref = read_reference(path)
    assert ref.has_time and ref.has_sync and ref.form == "taxel"
    assert ref.rows == 9 * len(samples) and len(ref.node_id) == len(samples)
    want = sorted(samples, key=lambda s: (s[2], s[0], s[1]))
    for k, (t, sync, node, force) in enumerate(want):
        assert (ref.time_s[k], ref.sync[k], ref.node_id[k]) == (t, sync, node)
        np.testing.assert_array_equal(ref.force_N[k], np.array(force).reshape(9, 3))


@given(st.floats(-1.5, 1.5), st.floats(-1.5, 1.5), st.lists(finite, min_size=3, max_size=3))
@settings(max_examples=200, deadline=None)
def test_a_point_force_is_spread_without_loss(u: float, v: float, force: list[float]) -> None:
    out = spread_point(np.array([u * PITCH]), np.array([v * PITCH]), np.array([force]), PITCH)
    np.testing.assert_allclose(out[0].sum(axis=0), force, rtol=1e-12, atol=1e-12)
    share = out[0, :, 2] / force[2] if force[2] else None
    if share is not None:
        assert np.all(share >= -1e-12)
        assert np.count_nonzero(np.abs(share) > 1e-12) <= 4  # the centres around the point


def test_a_point_on_a_centre_or_between_two() -> None:
    f = np.array([[0.1, -0.2, 2.0]])
    on = spread_point(np.array([PITCH]), np.array([-PITCH]), f, PITCH)[0]  # taxel 2
    np.testing.assert_array_equal(on[2], f[0])
    assert np.count_nonzero(on) == 3
    half = spread_point(np.array([PITCH / 2]), np.array([0.0]), f, PITCH)[0]  # taxels 4, 5
    np.testing.assert_allclose(half[4], f[0] / 2)
    np.testing.assert_allclose(half[5], f[0] / 2)
    edge = spread_point(np.array([1.4 * PITCH]), np.array([0.0]), f, PITCH)[0]
    np.testing.assert_array_equal(edge[5], f[0])  # beyond the outer centre: the edge taxel


def test_point_rows_of_one_sample_add_and_npz_reads_alike(tmp_path: Path) -> None:
    rows = ["time_s,node_id,x_m,y_m,fx_N,fy_N,fz_N",
            "0.5,2,0.0,0.0,0.0,0.0,1.0", f"0.5,2,{PITCH},{PITCH},0.0,0.0,2.0",
            "0.6,2,0.0,0.0,0.0,0.0,0.0"]
    (tmp_path / "p.csv").write_text("\n".join(rows) + "\n")
    ref = read_reference(tmp_path / "p.csv")
    assert ref.form == "point" and not ref.has_sync and list(ref.node_id) == [2, 2]
    assert ref.force_N[0, 4, 2] == 1.0 and ref.force_N[0, 8, 2] == 2.0
    assert not ref.force_N[1].any()  # a rest sample
    columns = {name: np.array([r.split(",")[k] for r in rows[1:]], dtype=float)
               for k, name in enumerate(rows[0].split(","))}
    np.savez(tmp_path / "p.npz", **columns)
    again = read_reference(tmp_path / "p.npz")
    np.testing.assert_array_equal(again.force_N, ref.force_N)


def test_a_sample_missing_a_taxel_is_counted_and_left_out(tmp_path: Path) -> None:
    lines = ["sync,node_id,taxel,fx_N,fy_N,fz_N"]
    lines += [f"5,1,{t},0,0,1" for t in range(9)]
    lines += [f"6,1,{t},0,0,1" for t in range(8)]  # taxel 8 missing
    lines += [f"7,1,{t},0,0,1" for t in range(9)]
    (tmp_path / "r.csv").write_text("\n".join(lines) + "\n")
    ref = read_reference(tmp_path / "r.csv")
    assert list(ref.sync) == [5, 7] and ref.incomplete == {1: 1}


def test_counters_without_time_keep_file_order_across_the_wrap(tmp_path: Path) -> None:
    lines = ["sync,node_id,taxel,fx_N,fy_N,fz_N"]
    for sync in (239, 240, 1, 2):
        lines += [f"{sync},1,{t},0,0,{sync}" for t in range(9)]
    (tmp_path / "r.csv").write_text("\n".join(lines) + "\n")
    ref = read_reference(tmp_path / "r.csv")
    assert list(ref.sync) == [239, 240, 1, 2] and not ref.has_time
    assert list(ref.force_N[:, 0, 2]) == [239, 240, 1, 2]


BAD = [
    ("time_s,node_id,taxel,fx_N,fy_N,fz_N\n1.0,1,0,0,0,abc\n", "row 2: fz_N: not a number"),
    ("time_s,node_id,taxel,fx_N,fy_N,fz_N\n1.0,1,0,0,0,nan\n", "row 2: fz_N: must be finite"),
    ("time_s,node_id,taxel,fx_N,fy_N,fz_N\n1.0,1,0,0,0,1\n1.0,1,0,0,0,1\n",
     "row 3: taxel 0 of this sample (node 1) given twice"),
    ("time_s,node_id,taxel,fx_N,fy_N,fz_N\n1.0,1,9,0,0,1\n", "row 2: taxel: 9 is not a taxel"),
    ("time_s,node_id,taxel,fx_N,fy_N,fz_N\n1.0,0,1,0,0,1\n", "row 2: node_id: 0 is not a node"),
    ("time_s,node_id,taxel,fx_N,fy_N,fz_N\n1.0,1,1.5,0,0,1\n", "row 2: taxel: must be a whole"),
    ("time_s,node_id,taxel,fx_N,fy_N,fz_N\n1.0,1,1,0,0\n", "row 2: 5 fields, the header names 6"),
    ("time_s,node_id,taxel,fx_N,fy_N,fz_N\n1.0,1,1,0,0,1", "row 2: cut short before its end"),
    ("time_s,node_id,taxel,fx_N,fy_N,fz_n\n", "row 1: unknown column 'fz_n'"),
    ("node_id,taxel,fx_N,fy_N,fz_N\n1,1,0,0,1\n", "row 1: needs a time_s or a sync column"),
    ("time_s,node_id,taxel,x_m,y_m,fx_N,fy_N,fz_N\n", "row 1: give either taxel or x_m"),
    ("time_s,node_id,x_m,y_m,fx_N,fy_N,fz_N\n1,1,0.03,0,0,0,1\n", "row 2: x_m: 0.03 is not on"),
    ("time_s,sync,node_id,taxel,fx_N,fy_N,fz_N\n1,0,1,0,0,0,1\n2,4,1,0,0,0,1\n",
     "row 2: sync: 0 (no counter) among rows that name one"),
    ("", "empty file"),
]


@pytest.mark.parametrize(("text", "message"), BAD)
def test_a_bad_file_names_its_row(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ReferenceFileError) as err:
        read_reference(path)
    assert str(err.value).startswith(f"{path}: ")
    assert message in str(err.value)


def test_bad_npz_and_unknown_suffix(tmp_path: Path) -> None:
    np.savez(tmp_path / "r.npz", time_s=np.zeros(3), node_id=np.ones(2), taxel=np.zeros(3),
             fx_N=np.zeros(3), fy_N=np.zeros(3), fz_N=np.zeros(3))
    with pytest.raises(ReferenceFileError, match="1-D and of one length"):
        read_reference(tmp_path / "r.npz")
    with pytest.raises(ReferenceFileError, match=r"unknown format '\.txt'"):
        read_reference(tmp_path / "r.txt")
    with pytest.raises(ReferenceFileError, match="no such file"):
        read_reference(tmp_path / "missing.csv")
