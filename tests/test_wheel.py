"""What ``pip install canskin`` puts on a machine: the four packages and the EDS files, no
test support, and ``skin bench`` and ``skin demo`` working from it alone."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from tests.support.rigs import children

ROOT = Path(__file__).resolve().parents[1]
INSTALLED = {"skin", "sim", "decoder", "canbus", "eds"}

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> tuple[zipfile.ZipFile, Path]:
    """The wheel pip builds from this checkout, and the folder it is unpacked into (what an
    install of a pure-Python wheel is, less the console script)."""
    out = tmp_path_factory.mktemp("wheel")
    source = out / "source"  # pip builds in the tree it is given: a copy, not the checkout
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(
        ".*", "build", "dist", "*.egg-info", "__pycache__"))
    built = children.run([sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", "-q",
                          "-w", str(out)], cwd=out, timeout=600)
    assert built.returncode == 0, built.stdout + built.stderr
    (wheel,) = out.glob("canskin-*.whl")
    site = out / "site"
    with zipfile.ZipFile(wheel) as archive:
        archive.extractall(site)
    return zipfile.ZipFile(wheel), site


def test_the_wheel_holds_the_product_and_nothing_else(
        installed: tuple[zipfile.ZipFile, Path]) -> None:
    archive, _ = installed
    names = archive.namelist()
    tops = {name.split("/")[0] for name in names if not name.split("/")[0].endswith(".dist-info")}
    assert tops == INSTALLED
    assert not [n for n in names if {"tests", "rigs", "support"} & set(n.split("/"))
                or Path(n).stem in {"mutants", "dataplane_pytest", "children", "ports", "waiting"}]
    assert {"eds/skin-patch.eds", "eds/skin-forces.eds"} <= set(names)
    assert "skin/benchmarks/dataplane.py" in names  # what skin bench runs is product
    top_level = next(n for n in names if n.endswith(".dist-info/top_level.txt"))
    assert set(archive.read(top_level).decode().split()) == INSTALLED


def _skin(site: Path, cwd: Path, *argv: str) -> subprocess.CompletedProcess[str]:
    """``skin ARGV`` with the unpacked wheel first on the path, from a folder outside the
    checkout: it finds the installed packages, not the checkout's."""
    return children.run([sys.executable, "-m", "skin.cli", *argv], cwd=cwd,
                        env={**_env(), "PYTHONPATH": str(site)}, timeout=300)


def _env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}


def test_skin_runs_from_the_install(installed: tuple[zipfile.ZipFile, Path],
                                    tmp_path: Path) -> None:
    _, site = installed
    where = children.run([sys.executable, "-c", "import skin, skin.benchmarks.sim, "
                          "skin.commands.demo.rig as r; print(skin.__file__, r.__file__)"],
                         cwd=tmp_path, env={**_env(), "PYTHONPATH": str(site)}, timeout=60)
    assert where.returncode == 0, where.stderr
    assert all(Path(f).is_relative_to(site) for f in where.stdout.split()), where.stdout

    demo = _skin(site, tmp_path, "demo", "--patches", "1", "--seconds", "1",
                 "--json", "demo.json")
    assert demo.returncode == 0, demo.stderr
    assert (tmp_path / "demo.json").stat().st_size > 0
    bench = _skin(site, tmp_path, "bench", "sim", "--quick", "--json", "sim.json")
    assert bench.returncode == 0, bench.stderr
    assert (tmp_path / "sim.json").stat().st_size > 0
