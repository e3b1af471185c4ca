"""Every kind of OS error a command meets ends in one line on stderr and exit status 1, and
leaves nothing half-written: an input that is missing or a directory, an output in a
read-only folder, on a full disk, or where a directory stands.

A read-only folder is read-only for root too here: the command runs without the
capabilities that let root write anywhere (util-linux's ``setpriv``). A full disk is a file
size limit (``RLIMIT_FSIZE``: a write past it fails as a write to a full disk does; Python
ignores the SIGXFSZ that comes with it). Both run the command in a process of its own.
"""

from __future__ import annotations

import os
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from skin.cli import main
from tests.support.rigs.children import run

RECORDING = Path(__file__).parents[1] / "files" / "recordings" / "good.log"
# The command in a child: an optional file size limit, then skin's own main.
LIMITED = """
import resource, sys
size = int(sys.argv[1])
if size >= 0:
    resource.setrlimit(resource.RLIMIT_FSIZE, (size, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
from skin.cli import main
sys.exit(main(sys.argv[2:]))
"""


@dataclass(frozen=True)
class Command:
    """``skin ARGS`` with ``{in}`` and ``{out}`` put in; ``output``: the file it writes."""

    args: tuple[str, ...]
    input: str | None = None  # what {in} stands for: "dataset" or "recording"
    output: str | None = None  # the output file's name

    def argv(self, folder: Path, *, source: Path | None = None,
             target: Path | None = None) -> list[str]:
        out = target if target is not None else folder / (self.output or "out")
        given = {"{in}": str(source) if source is not None else "", "{out}": str(out)}
        return [given.get(arg, arg) for arg in self.args]


COMMANDS = {
    "sim-dataset": Command(("sim", "dataset", "paper", "-n", "200", "-o", "{out}"),
                           output="d.npz"),
    "train": Command(("train", "analytic", "--data", "{in}", "-o", "{out}"), input="dataset",
                     output="m.msgpack"),
    "plan-json": Command(("plan", "--patches", "2", "--rate", "100", "--json", "{out}"),
                         output="plan.json"),
    "sniff-record": Command(("sniff", "-i", "virtual", "-c", "os-errors", "--seconds", "0.2",
                             "--view", "none", "--record", "{out}"), output="r.asc"),
    "replay": Command(("replay", "{in}", "-i", "virtual", "-c", "os-errors", "--fast"),
                      input="recording"),
}
WRITERS = [name for name, c in COMMANDS.items() if c.output]
READERS = [name for name, c in COMMANDS.items() if c.input]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("data") / "paper.npz"
    assert main(["sim", "dataset", "paper", "-n", "200", "-o", str(path)]) == 0
    return path


def _inputs(command: Command, dataset: Path) -> Path | None:
    return {"dataset": dataset, "recording": RECORDING, None: None}[command.input]


def _one_line(code: int, err: str, names: str, *, status: int = 1) -> None:
    assert code == status, err
    lines = err.strip("\n").splitlines()
    assert len(lines) == 1 and lines[0].startswith("skin") and ": error: " in lines[0], err
    assert names in lines[0] and "Traceback" not in err, err
    assert "unexpected" not in lines[0], err  # an OS error is said as one, not as a surprise


def _nothing_left(folder: Path, before: set[str]) -> None:
    """No output and no temporary file appeared (what was there is untouched)."""
    assert {p.name for p in folder.iterdir()} == before


@pytest.mark.parametrize("name", READERS)
@pytest.mark.parametrize("kind", ["missing", "a-directory"])
def test_an_input_that_cannot_be_read_is_one_line(
        name: str, kind: str, tmp_path: Path, dataset: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    command = COMMANDS[name]
    source = tmp_path / "in.npz"
    if kind == "a-directory":
        source.mkdir()
    before = {p.name for p in tmp_path.iterdir()}
    code = main(command.argv(tmp_path, source=source))
    _one_line(code, capsys.readouterr().err, "in.npz")
    _nothing_left(tmp_path, before)


@pytest.mark.parametrize("name", WRITERS)
def test_an_output_where_a_directory_stands_is_one_line(
        name: str, tmp_path: Path, dataset: Path, capsys: pytest.CaptureFixture[str]) -> None:
    command = COMMANDS[name]
    target = tmp_path / (command.output or "")
    target.mkdir()
    (target / "kept").write_text("kept")
    before = {p.name for p in tmp_path.iterdir()}
    with pytest.raises(SystemExit) as refused:  # the output option's own check, at parse time
        main(command.argv(tmp_path, source=_inputs(command, dataset), target=target))
    _one_line(refused.value.code, capsys.readouterr().err, target.name, status=2)  # usage
    _nothing_left(tmp_path, before)
    assert (target / "kept").read_text() == "kept"


def _child(prefix: list[str], size: int, argv: list[str], folder: Path) -> tuple[int, str]:
    done = run([*prefix, sys.executable, "-c", LIMITED, str(size), *argv], cwd=folder,
               timeout=120, env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[2])})
    return done.returncode, done.stderr


def _without_root_powers() -> list[str]:
    """A prefix that runs a command unable to write where its permissions say no."""
    if os.getuid() != 0:
        return []
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        pytest.skip("root writes anywhere and util-linux's setpriv is not here to stop it")
    return [setpriv, "--bounding-set", "-dac_override,-dac_read_search"]


Setup = Callable[[Path], None]


@pytest.mark.parametrize("name", WRITERS)
def test_an_output_in_a_read_only_folder_is_one_line(name: str, tmp_path: Path,
                                                     dataset: Path) -> None:
    command = COMMANDS[name]
    folder = tmp_path / "read-only"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        code, err = _child(_without_root_powers(), -1,
                           command.argv(folder, source=_inputs(command, dataset)), tmp_path)
        _one_line(code, err, "read-only")
        assert list(folder.iterdir()) == []
    finally:
        folder.chmod(0o755)


@pytest.mark.parametrize("name", WRITERS)
def test_an_output_on_a_full_disk_is_one_line_and_leaves_nothing(name: str, tmp_path: Path,
                                                                 dataset: Path) -> None:
    command = COMMANDS[name]
    folder = tmp_path / "full"
    folder.mkdir()
    code, err = _child([], 64, command.argv(folder, source=_inputs(command, dataset)),
                       tmp_path)
    _one_line(code, err, command.output or "")
    # a recording is written as it goes: it keeps what reached the disk (docs/sniffer.md)
    assert list(folder.iterdir()) == [] or name == "sniff-record", list(folder.iterdir())


@pytest.mark.parametrize("error", [PermissionError(13, "Permission denied", "/dev/can0"),
                                   OSError(100, "Network is down"),
                                   FileNotFoundError(2, "No such file or directory", "x.dbc")])
def test_an_os_error_no_command_foresaw_is_still_one_line(
        error: OSError, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The last line of defence: an OS error that escapes a command (a library's, from a
    path no command wraps) is said as an OS error in one line, exit status 1."""
    import skin.commands.plan as plan

    def fails(args: object) -> int:
        raise error

    monkeypatch.setattr(plan, "_plan", fails)
    code = main(["plan", "--patches", "16", "--rate", "100"])
    _one_line(code, capsys.readouterr().err, error.strerror or "")
