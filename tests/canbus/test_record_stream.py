"""A recording is a stream: complete on disk after every write, a cut tail read up to its last
whole frame with ``partial=True``, rotation into files that each stand alone."""

from __future__ import annotations

import logging
import shutil
import time
from pathlib import Path

import can
import pytest

from canbus.tools import recorder as recorder_module
from canbus.tools.recorder import Recorder, rotated_path
from canbus.tools.recording import Recording
from skin.errors import RecordingError
from tests.support.rigs.waiting import wait_until

PROMISED_LOSS_S = 0.1
"""docs/sniffer.md: kill -9 loses at most the last 0.1 s of frames."""
FORMATS = [".log", ".asc", ".blf", ".pcap"]
T0 = 1_700_000_000.0
BLF_HEADER = 144


def _numbered(count: int, start: int = 0) -> list[can.Message]:
    return [can.Message(timestamp=T0 + 0.001 * k, arbitration_id=0x181 + k % 3,
                        data=k.to_bytes(4, "little"), is_extended_id=False)
            for k in range(start, start + count)]


def _numbers(messages: list[can.Message]) -> list[int]:
    return [int.from_bytes(m.data, "little") for m in messages]


def _read(path: Path, *, partial: bool = False) -> tuple[list[int], RecordingError | None]:
    with Recording(path, partial=partial) as recording:
        return _numbers(list(recording)), recording.cut


def _python_can(path: Path) -> list[int]:
    with can.LogReader(path) as reader:  # .pcap: ours, found by python-can's entry point
        return _numbers(list(reader))


def _snapshot(path: Path, frames: int, into: Path) -> bytes:
    """The file as it is on disk once it holds ``frames`` frames (copied while recording)."""

    def copied() -> bool:
        shutil.copyfile(path, into)
        return len(_read(into)[0]) == frames  # a strict read: complete at every write

    wait_until(copied, what=f"{path} holding {frames} frames")
    return into.read_bytes()


class _Clock:
    """The recorder's clock, moved by the test (its ``time`` module, as the recorder sees it)."""

    def __init__(self) -> None:
        self.now = 1000.0

    def monotonic(self) -> float:
        return self.now


@pytest.mark.parametrize("suffix", FORMATS)
def test_a_frame_is_on_disk_flush_s_after_it_came_and_a_stop_writes_out_the_rest(
        tmp_path: Path, suffix: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """The kill -9 bound (at most 0.1 s lost) on the recorder's own clock, which the test
    moves: however the machine runs, a frame received is on disk once 0.1 s has passed;
    and a stop writes out what is queued, not yet due (SIGTERM keeps every frame)."""
    clock = _Clock()
    monkeypatch.setattr(recorder_module, "time", clock)
    path = tmp_path / f"run{suffix}"
    recorder = Recorder(path)
    try:
        for msg in _numbered(10):
            recorder.on_message_received(msg)
        wait_until(lambda: recorder.written == 10, what="the frames handed to the writer")
        clock.now += PROMISED_LOSS_S
        wait_until(lambda: _read(path)[0] == list(range(10)), timeout=10,
                   what=f"the frames on disk {PROMISED_LOSS_S} s after they came")
        for msg in _numbered(5, start=10):  # not due: the clock stands still
            recorder.on_message_received(msg)
    finally:
        recorder.stop()
    assert _read(path) == (list(range(15)), None)


@pytest.mark.parametrize("suffix", FORMATS)
def test_complete_on_disk_at_every_write(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"run{suffix}"
    recorder = Recorder(path)
    assert _read(path) == ([], None) and _python_can(path) == []  # valid from the start
    for msg in _numbered(50):
        recorder.on_message_received(msg)
    first = _snapshot(path, 50, tmp_path / f"a{suffix}")
    assert _python_can(tmp_path / f"a{suffix}") == list(range(50))
    for msg in _numbered(50, start=50):
        recorder.on_message_received(msg)
    second = _snapshot(path, 100, tmp_path / f"b{suffix}")
    assert _python_can(tmp_path / f"b{suffix}") == list(range(100))
    if suffix == ".asc":
        assert first.endswith(b"\nEnd TriggerBlock\n") and second.endswith(b"\nEnd TriggerBlock\n")
    if suffix == ".blf":
        with can.BLFReader(tmp_path / f"b{suffix}") as reader:
            assert (reader.object_count, reader.file_size) == (100, len(second))
    recorder.stop()
    assert _read(path) == (list(range(100)), None)
    assert _python_can(path) == list(range(100))


def _killed_files(suffix: str, before: bytes, after: bytes) -> list[tuple[int, bytes]]:
    """Every file a kill -9 inside the write from ``before`` to ``after`` can leave."""
    if suffix == ".blf":  # containers appended, then the header rewritten
        header = before[:BLF_HEADER]
        return [(cut, header + after[BLF_HEADER:cut]) for cut in range(len(before), len(after) + 1)]
    # the batch (and .asc's footer after it) written over the old footer, cut anywhere
    footer = len(b"End TriggerBlock\n") if suffix == ".asc" else 0
    return [(cut, after[:cut] + before[cut:]) for cut in range(len(before) - footer,
                                                               len(after) + 1)]


@pytest.mark.parametrize("suffix", FORMATS)
def test_a_kill_inside_a_write_is_read_up_to_the_last_whole_frame(tmp_path: Path,
                                                                   suffix: str) -> None:
    path = tmp_path / f"run{suffix}"
    recorder = Recorder(path)
    for msg in _numbered(40):
        recorder.on_message_received(msg)
    before = _snapshot(path, 40, tmp_path / f"a{suffix}")
    for msg in _numbered(4, start=40):
        recorder.on_message_received(msg)
    after = _snapshot(path, 44, tmp_path / f"b{suffix}")
    recorder.stop()
    killed = tmp_path / f"killed{suffix}"
    strict_whole = 0
    files = _killed_files(suffix, before, after)
    for cut, content in files:
        killed.write_bytes(content)
        got, dropped = _read(killed, partial=True)
        # a prefix of the frames, holding all those of the write before
        assert got == list(range(len(got))) and len(got) >= 40, cut
        if dropped is None:  # the write ended whole here: complete, strictly
            assert _read(killed) == (got, None), cut
            strict_whole += 1
        else:  # a strict read stops at the same frame, with the same words
            with pytest.raises(RecordingError) as info:
                _read(killed)
            assert str(info.value) == str(dropped), cut
    assert 1 <= strict_whole < len(files)  # complete where the write ended whole
    assert _read(killed) == (list(range(44)), None)


def test_partial_still_refuses_damage_before_the_end(tmp_path: Path) -> None:
    path = tmp_path / "run.log"
    recorder = Recorder(path)
    for msg in _numbered(5):
        recorder.on_message_received(msg)
    recorder.stop()
    lines = path.read_text().splitlines(keepends=True)
    lines[2] = lines[2].replace("#", "#G")
    path.write_text("".join(lines))
    with pytest.raises(RecordingError, match="frame 3: line 3: not a candump -L frame"):
        _read(path, partial=True)


@pytest.mark.parametrize("suffix", [".log", ".asc", ".pcap"])
def test_rotation_by_size_gives_files_that_each_stand_alone(tmp_path: Path,
                                                            suffix: str) -> None:
    path = tmp_path / f"run{suffix}"
    limit = 600
    recorder = Recorder(path, rotate_bytes=limit)
    for msg in _numbered(100):
        recorder.on_message_received(msg)
    recorder.stop()
    assert recorder.files == [rotated_path(path, k) for k in range(len(recorder.files))]
    assert sorted(tmp_path.iterdir()) == sorted(recorder.files)
    assert len(recorder.files) >= 4
    assert recorder.files[1].name == f"run.001{suffix}"
    numbers: list[int] = []
    for file in recorder.files:
        got, _ = _read(file)  # strict: each a whole recording
        assert got and _python_can(file) == got
        numbers += got
        if file != recorder.files[-1]:  # closed at the first frame that reached the limit
            assert limit <= file.stat().st_size < limit + 80
    assert numbers == list(range(100))


@pytest.mark.parametrize("suffix", [".asc", ".blf"])
def test_rotation_by_time(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"run{suffix}"
    recorder = Recorder(path, rotate_s=0.2)
    for batch in range(16):
        for msg in _numbered(10, start=10 * batch):
            recorder.on_message_received(msg)
        time.sleep(0.05)  # pacing: 16 batches over at least 0.8 s, rotated every 0.2 s
    recorder.stop()
    assert len(recorder.files) >= 2
    numbers: list[int] = []
    for file in recorder.files:
        got, _ = _read(file)
        assert _python_can(file) == got
        numbers += got
    assert numbers == list(range(160))


def test_blf_rotates_by_its_compressed_size(tmp_path: Path) -> None:
    path = tmp_path / "run.blf"
    recorder = Recorder(path, rotate_bytes=400)
    for batch in range(8):
        for msg in _numbered(20, start=20 * batch):
            recorder.on_message_received(msg)
        # a checkpoint: a container of the batch, the size on disk
        total = 20 * (batch + 1)
        wait_until(lambda: sum(len(_read(f)[0]) for f in recorder.files) == total,  # noqa: B023
                   what=f"batch {batch} on disk")
    recorder.stop()
    assert len(recorder.files) >= 2
    numbers: list[int] = []
    for file in recorder.files:
        got, _ = _read(file)
        numbers += got
        if file != recorder.files[-1]:
            assert file.stat().st_size >= 400
    assert numbers == list(range(160))


def test_numbered_files_of_an_earlier_recording_are_named(tmp_path: Path,
                                                          caplog: pytest.LogCaptureFixture) -> None:
    (tmp_path / "run.004.log").write_text("")
    with caplog.at_level(logging.WARNING, logger="canbus.tools.recorder"):
        Recorder(tmp_path / "run.log", rotate_s=60).stop()
    assert "numbered file(s) of an earlier recording are there (run.004.log)" in caplog.text


def test_rotated_names() -> None:
    assert rotated_path("d/run.log", 0) == Path("d/run.log")
    assert rotated_path("d/run.log", 1) == Path("d/run.001.log")
    assert rotated_path("run.x.blf", 1234) == Path("run.x.1234.blf")
