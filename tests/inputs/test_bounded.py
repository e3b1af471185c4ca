"""Bounded memory and time, seen from outside: ``skin`` in a process whose address space
is capped (as ``ulimit -v`` caps it) refuses what would not fit with the figure, in one
line, instead of being killed or swapping; and what used to loop for ever ends: each
command is a child (tests.support.rigs.children) with a deadline, killed and failed if it
runs on."""

from __future__ import annotations

import io
import os
import struct
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from tests.inputs.blf_files import blf_file, can_objects
from tests.support.rigs import children

CAP = 3 << 30
"""The address space of the process (numpy and its BLAS alone reserve most of a GiB)."""
HANG_S = 240
"""A command still running after this long is hung (each takes seconds): below the test's
own time-out, so the failure names the command."""
CAPPED = ("import resource, runpy, sys; cap = int(sys.argv.pop(1)); "
          "resource.setrlimit(resource.RLIMIT_AS, (cap, cap)); "
          "runpy.run_module('skin.cli', run_name='__main__', alter_sys=True)")
"""``python -m skin.cli`` with its address space capped before skin or numpy is imported."""


def _skin(*argv: str | Path) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "SKIN_MEMORY_BUDGET"}
    env["OPENBLAS_NUM_THREADS"] = "1"
    return children.run([sys.executable, "-c", CAPPED, str(CAP), *map(str, argv)], env=env,
                        timeout=HANG_S)


def _one_line(result: subprocess.CompletedProcess[str], *words: str) -> None:
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.returncode == 1, result.stderr[-2000:]
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr[-2000:]
    for word in words:
        assert word in lines[0], lines[0]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("bounded") / "d.npz"
    assert _skin("sim", "dataset", "paper", "-n", "50", "-o", path).returncode == 0
    return path


def test_a_dataset_larger_than_the_machine(tmp_path: Path) -> None:
    _one_line(_skin("sim", "dataset", "paper", "-n", "1000000000", "-o", tmp_path / "d.npz"),
              "n: 1000000000 samples", "GiB of memory, more than the budget")
    assert list(tmp_path.iterdir()) == []


def test_a_network_larger_than_the_machine(tmp_path: Path, dataset: Path) -> None:
    _one_line(_skin("train", "lm-mlp", "--hidden", "1000", "--data", dataset, "-o",
                    tmp_path / "m.msgpack"), "hidden: ", "19009 weights", "more than the budget")


def test_an_array_header_that_declares_terabytes(tmp_path: Path, dataset: Path) -> None:
    with np.load(dataset) as npz:
        members = {k: npz[k] for k in npz.files}
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False,
                                                  "shape": (10**12, 1, 9, 1)})
    path = tmp_path / "rows.npz"
    with zipfile.ZipFile(path, "w") as archive:
        for name, array in members.items():
            data = io.BytesIO()
            np.lib.format.write_array(data, array)
            if name == "resistance_ohm":
                body = data.getvalue()
                data = io.BytesIO(header.getvalue() + body[body.index(b"\n") + 1:])
            archive.writestr(f"{name}.npy", data.getvalue())
    _one_line(_skin("eval", "analytic", path), str(path), "resistance_ohm",
              "(1000000000000, 1, 9, 1)")


def test_a_blf_object_of_size_zero_ends(tmp_path: Path) -> None:
    inner = bytearray(can_objects(2))
    struct.pack_into("<L", inner, 8, 0)
    path = tmp_path / "zero.blf"
    path.write_bytes(blf_file(bytes(inner)))
    _one_line(_skin("replay", path, "--fast", "-i", "virtual"), str(path), "frame 1",
              "declares 0 bytes")


def test_an_eds_mapping_count_of_0x7fffffff(tmp_path: Path) -> None:
    text = (Path(__file__).resolve().parents[2] / "eds" / "skin-patch.eds").read_text()
    path = tmp_path / "count.eds"
    path.write_text(text.replace("DefaultValue=4\nPDOMapping=0\nLowLimit=0\nHighLimit=64",
                                 "DataType=0x0007\nDefaultValue=0x7FFFFFFF\nPDOMapping=0", 1)
                    .replace("DataType=0x0005\nAccessType=rw\nDataType=0x0007",
                             "AccessType=rw\nDataType=0x0007", 1))
    result = _skin("eds", "check", path)
    assert result.returncode == 1 and "Traceback" not in result.stderr, result.stderr
    assert "0x7FFFFFFF" in result.stderr or "2147483647" in result.stderr
