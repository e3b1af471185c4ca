"""Where results go: only regular files. A FIFO, a device, a folder or a missing folder is
refused for every output option before any work; errors name the user's path, never the
temporary file; a recording never truncates an existing file before it can write."""

from __future__ import annotations

import argparse
import errno
import os
import stat
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from skin.atomic import atomic_write
from skin.cli import _commands, build_parser
from skin.commands.common import argtypes
from skin.errors import OutputError
from tests.inputs.conftest import examples
from tests.inputs.hostile import fingerprint, refused, run


def _output_options() -> list[tuple[list[str], str]]:
    parser = build_parser()
    top = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return [(command.prog.split()[1:], action.option_strings[-1])
            for command in _commands(top) for action in command._actions
            if action.type is argtypes.output_file]


OPTIONS = _output_options()


def test_every_result_option_is_checked() -> None:
    flags = {flag for _, flag in OPTIONS}
    assert {"--json", "--output", "--record", "--png", "--gif", "--truth", "--report",
            "--config-snippet", "--plot"} <= flags
    assert len(OPTIONS) >= 25


@pytest.fixture(scope="module")
def targets(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("targets")
    os.mkfifo(folder / "fifo")
    (folder / "folder").mkdir()
    (folder / "folder" / "kept").write_text("kept")
    return {"fifo": folder / "fifo", "device": Path("/dev/null"), "folder": folder / "folder",
            "missing": folder / "absent" / "out.json", "empty": Path("")}


@examples(40)
@given(option=st.sampled_from(OPTIONS),
       kind=st.sampled_from(("fifo", "device", "folder", "missing")))
def test_no_result_goes_to_what_is_not_a_regular_file(targets: dict[str, Path],
                                                      option: tuple[list[str], str],
                                                      kind: str) -> None:
    path, flag = option
    target = targets[kind]
    before = fingerprint(target.parent) if kind != "device" else {}
    result = run(*path, f"{flag}={target}")
    refused(result)
    assert result.code == 2 and str(target) in result.lines[0]
    assert stat.S_ISFIFO(targets["fifo"].stat().st_mode)
    assert stat.S_ISCHR(Path("/dev/null").stat().st_mode)
    if kind != "device":
        assert fingerprint(target.parent) == before


def test_json_onto_dev_null_leaves_it_a_device(tmp_path: Path) -> None:
    result = run("plan", "--patches", "4", "--rate", "100", "--json", "/dev/null")
    refused(result)
    assert "'/dev/null': is a character device" in result.lines[0]
    assert stat.S_ISCHR(Path("/dev/null").stat().st_mode)


def test_a_full_disk_names_the_users_path(tmp_path: Path) -> None:
    target = tmp_path / "out.json"
    target.write_text("the previous result")

    def write() -> None:
        with atomic_write(target) as handle:
            handle.write(b"{}")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp_path / ".x.tmp"))

    with pytest.raises(OutputError) as info:
        write()
    assert str(info.value) == f"cannot write {str(target)!r}: No space left on device"
    assert target.read_text() == "the previous result"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]


def test_a_read_only_folder_names_the_users_path(tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*args: object, **kwargs: object) -> int:
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), "/somewhere/.out.json.1.tmp")

    monkeypatch.setattr(os, "open", refuse)
    result = run("plan", "--patches", "1", "--rate", "100", "--json", tmp_path / "out.json")
    refused(result)
    assert f"cannot write '{tmp_path / 'out.json'}': Read-only file system" in result.lines[0]
    assert ".tmp" not in result.lines[0]


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf", ".pcap"])
def test_a_recording_on_a_full_disk_keeps_the_existing_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, suffix: str) -> None:
    from canbus.tools.recorder import Recorder
    from canbus.tools.segments import LiveBLFWriter

    target = tmp_path / f"run{suffix}"
    target.write_bytes(b"an earlier recording")

    def full(*args: object, **kwargs: object) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "pwrite", full)  # .asc, .pcap write their header with pwrite
    monkeypatch.setattr(os, "posix_fallocate", full)  # .log has none: room is reserved
    monkeypatch.setattr(LiveBLFWriter, "checkpoint", full)  # .blf: its first checkpoint
    with pytest.raises(OutputError, match=f"cannot write '{target}': No space left"):
        Recorder(target, channel="can0").stop()
    assert target.read_bytes() == b"an earlier recording"
    assert sorted(p.name for p in tmp_path.iterdir()) == [target.name]
