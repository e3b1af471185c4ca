"""An .mcap recording: frames and force samples in ROS 2 messages that a reader independent
of canskin (the ``mcap`` library and its ROS 2 decoder, from the schemas the file carries)
decodes to the same values; a stream of whole chunks while written, indexed once closed,
read up to its cut after a kill; a bad path is one line and no file."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest

pytest.importorskip("mcap_ros2", reason="the mcap extra is not installed")

from mcap.reader import make_reader
from mcap.stream_reader import StreamReader

from canbus.master.channel import ForceFrame
from canbus.offline.mcap import read_forces
from canbus.tools import recorder as recorder_module
from canbus.tools.mcap_messages import Placement, stamp_ns
from canbus.tools.recorder import Recorder
from canbus.tools.recording import Recording
from skin.cli import main
from skin.errors import OutputError, RecordingError
from tests.canbus.mcap_independent import column, decoded
from tests.support.rigs.waiting import wait_until

T0 = 1_700_000_000.123456


def _frames() -> list[can.Message]:
    out = [can.Message(timestamp=T0 + 0.000731 * k, arbitration_id=0x181 + k % 5,
                       data=bytes((k + j) % 256 for j in range(k % 9)), is_extended_id=False,
                       channel="can0") for k in range(300)]
    out += [can.Message(timestamp=T0 + 1, arbitration_id=0x1ABCDEF0, data=b"\x01\x02",
                        is_extended_id=True, channel="can0"),
            can.Message(timestamp=T0 + 2, arbitration_id=0x701, is_remote_frame=True, dlc=4,
                        is_extended_id=False, channel="can0"),
            can.Message(timestamp=T0 + 3, arbitration_id=0x281, data=bytes(range(64)),
                        is_fd=True, is_extended_id=False, channel="can0")]
    return out


def _key(msg: can.Message) -> tuple[object, ...]:
    return (msg.timestamp, msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame,
            msg.is_fd, msg.dlc, bytes(msg.data))


def _sample(patch: int, cycle: int, seed: int) -> ForceFrame:
    rng = np.random.default_rng(seed)
    valid = rng.random(9) > 0.2
    force = np.where(valid[:, None], rng.normal(0, 2, (9, 3)), 0.0)
    return ForceFrame(patch=patch, force_node=patch + 64, cycle=cycle,
                      sync_counter=cycle % 240 + 1, timestamp=T0 + 0.01 * cycle + 1e-7 * patch,
                      force_N=force, valid=valid, reason=np.where(valid, 0, 3).astype(np.uint8),
                      complete=bool(cycle % 3), published=True)


def test_frames_read_back_bit_for_bit_by_canskin_and_by_the_mcap_library(
        tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    recorder = Recorder(path)
    sent = _frames()
    for msg in sent:
        recorder.on_message_received(msg)
    recorder.stop()
    with Recording(path) as recording:
        assert [_key(m) for m in recording] == [_key(m) for m in sent]
    messages = decoded(path)
    classic = [d for t, d in messages if t == "/can/frames"]
    fd = [d for t, d in messages if t == "/can/fd_frames"]
    assert len(classic) == len(sent) - 1 and len(fd) == 1
    for msg, frame in zip(sent[:-1], classic, strict=True):
        assert (frame.id, frame.is_extended, frame.is_rtr, frame.dlc) == \
            (msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, msg.dlc)
        assert bytes(frame.data)[:len(msg.data)] == bytes(msg.data)
        assert frame.header.stamp.sec * 10**9 + frame.header.stamp.nanosec == \
            stamp_ns(msg.timestamp)
        assert frame.header.frame_id == "can0"
    assert (fd[0].id, fd[0].len, bytes(fd[0].data)) == (0x281, 64, bytes(range(64)))
    with path.open("rb") as file:  # closed: indexed, with its statistics
        summary = make_reader(file).get_summary()
    assert summary is not None and summary.chunk_indexes
    assert summary.statistics.message_count == len(sent)


def test_samples_read_back_bit_for_bit_with_tf_static_from_the_placements(
        tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    recorder = Recorder(path, placements=[Placement(1, (0.1, -0.2), 90.0, 0.015),
                                          Placement(2, (0.0, 0.3), 0.0, 0.015)])
    samples = [_sample(patch, cycle, 10 * cycle + patch) for cycle in range(1, 30)
               for patch in (1, 2)]
    for sample in samples:
        recorder.on_forces(sample)
    recorder.stop()
    back = list(read_forces(str(path)))
    assert len(back) == len(samples)
    for a, b in zip(samples, back, strict=True):
        assert (a.patch, a.force_node, a.cycle, a.sync_counter, a.complete, a.published,
                a.timestamp) == (b.patch, b.force_node, b.cycle, b.sync_counter, b.complete,
                                 b.published, b.timestamp)
        assert a.force_N.tobytes() == b.force_N.tobytes()
        assert np.array_equal(a.valid, b.valid) and np.array_equal(a.reason, b.reason)
    # the independent reader: the cloud's own field table gives the forces and the mask
    clouds = [d for t, d in decoded(path) if t.endswith("/taxels")]
    by_key = {(s.patch, s.cycle): s for s in samples}
    assert len(clouds) == len(samples)
    for cloud in clouds:
        types = {f.name: f.datatype for f in cloud.fields}
        assert types["x"] == 7 and types["fz"] == 8  # FLOAT32 positions, FLOAT64 forces
        sample = by_key[(int(column(cloud, "patch", "u1")[0]),
                         int(column(cloud, "cycle", "<u4")[0]))]
        force = np.stack([column(cloud, a, "<f8") for a in ("fx", "fy", "fz")], axis=1)
        assert force.tobytes() == sample.force_N.tobytes()
        assert column(cloud, "valid", "u1").astype(bool).tolist() == sample.valid.tolist()
        assert cloud.header.frame_id == f"skin_patch_{sample.patch}"
    tf = [d for t, d in decoded(path) if t == "/tf_static"]
    assert len(tf) == 1
    placed = {t.child_frame_id: t.transform for t in tf[0].transforms}
    one = placed["skin_patch_1"]
    assert (one.translation.x, one.translation.y) == (0.1, -0.2)
    assert one.rotation.z == pytest.approx(2 ** -0.5) and one.rotation.w == pytest.approx(2 ** -0.5)


class _Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def monotonic(self) -> float:
        return self.now


def _stream_frames(path: Path) -> int:
    """The /can/frames messages the mcap library's stream reader gets before the end or a
    cut (a file whose writer did not finish has no footer)."""
    count = 0
    with path.open("rb") as file:
        try:
            for record in StreamReader(file).records:
                count += type(record).__name__ == "Message"
        except Exception:  # the documented tail: the end of a file without its footer
            pass
    return count


def test_a_frame_is_in_a_whole_chunk_on_disk_flush_s_after_it_came(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The kill -9 bound on the recorder's clock, which the test moves: a frame received is
    in a chunk on disk once FLUSH_S has passed, read by canskin (partial: the file has no
    footer yet) and by the mcap library; the stop closes the file with its index."""
    clock = _Clock()
    monkeypatch.setattr(recorder_module, "time", clock)
    path = tmp_path / "run.mcap"
    recorder = Recorder(path)
    copy = tmp_path / "copy.mcap"
    try:
        for msg in _frames()[:10]:
            recorder.on_message_received(msg)
        wait_until(lambda: recorder.written == 10, what="the frames handed to the writer")
        clock.now += recorder_module.FLUSH_S

        def on_disk() -> bool:
            shutil.copyfile(path, copy)
            return _stream_frames(copy) == 10

        wait_until(on_disk, timeout=10, what="the frames on disk FLUSH_S after they came")
        with Recording(copy, partial=True) as recording:
            assert len(list(recording)) == 10
            assert recording.cut is not None and "footer" in str(recording.cut)
        with pytest.raises(RecordingError, match="ends before its footer"):
            list(Recording(copy))
    finally:
        recorder.stop()
    assert len(list(Recording(path))) == 10


def test_a_kill_inside_a_write_is_read_up_to_the_last_whole_chunk(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    recorder = Recorder(path)
    sent = _frames()
    copy = tmp_path / "copy.mcap"

    def snapshot(frames: int) -> bytes:
        def there() -> bool:
            shutil.copyfile(path, copy)
            return _stream_frames(copy) == frames
        wait_until(there, what=f"{frames} frames on disk")
        return copy.read_bytes()

    for msg in sent[:40]:
        recorder.on_message_received(msg)
    before = snapshot(40)
    for msg in sent[40:44]:
        recorder.on_message_received(msg)
    after = snapshot(44)
    recorder.stop()
    assert after.startswith(before)
    killed = tmp_path / "killed.mcap"
    for cut in range(len(before), len(after) + 1):
        killed.write_bytes(after[:cut])
        with Recording(killed, partial=True) as recording:
            got = [_key(m) for m in recording]
        assert got in ([_key(m) for m in sent[:40]], [_key(m) for m in sent[:44]]), cut
        assert _stream_frames(killed) == len(got), cut


def test_a_bad_path_is_one_line_and_no_file(tmp_path: Path) -> None:
    with pytest.raises(OutputError, match="cannot write"):
        Recorder(tmp_path / "no" / "run.mcap")
    assert not (tmp_path / "no").exists()


def test_skin_decode_to_mcap_refuses_a_folder_it_cannot_write(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    recording = tmp_path / "run.log"
    recording.write_text("(1.000000) can0 181#00\n")
    config = tmp_path / "host.toml"
    config.write_text("[[patches]]\nnode_id = 1\n")
    with pytest.raises(SystemExit) as stop:
        main(["decode", str(recording), "--config", str(config), "-o",
              str(tmp_path / "missing" / "forces.mcap")])
    assert stop.value.code != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "forces.mcap" in err[0]


def test_a_host_on_an_in_process_bus_records_its_samples_in_its_own_process(
        tmp_path: Path) -> None:
    """``skin run --record`` on a virtual bus (which no other process hears): the recorder
    thread beside the host holds every sample the API gave, bit for bit, and the frames."""
    import canopen

    from canbus.device.patch_server import PatchServer
    from canbus.device.source import ArraySource
    from canbus.master.busconfig import BusConfig
    from canbus.master.host import HostManager
    from canbus.master.hostconfig import HostConfig, PatchConfig
    from skin.commands.common.hostrecord import recording
    from tests.support.rigs.zenoh_host import presses

    channel = "mcap-in-process"
    config = HostConfig(patches=(PatchConfig(1, position_m=(0.0, 0.1)), PatchConfig(2)),
                        sync_period_ms=20.0, scan_ms=300, heartbeat_ms=500,
                        buses=(BusConfig(interface="virtual", channel=channel),))
    device = canopen.Network()
    device.NOTIFIER_CYCLE = 0.05
    device.connect(interface="virtual", channel=channel)
    bus = can.Bus(interface="virtual", channel=channel)
    api: list[ForceFrame] = []
    path = tmp_path / "run.mcap"
    try:
        with PatchServer(device, ArraySource(presses(40, 2), (1, 2))):
            host = HostManager(bus, config)
            host.on_forces(api.append)
            with recording(str(path), config, host) as recorded:
                host.start()
                try:
                    assert host.wait_operational(timeout=15.0), host.health()
                    wait_until(lambda: len(api) >= 40, what="40 samples")
                finally:
                    host.stop()
    finally:
        bus.shutdown()
        device.disconnect()
    assert recorded.samples == len(api) and recorded.frames > 100
    back = {(f.patch, f.cycle): f for f in read_forces(str(path))}
    assert len(back) == len(api)
    for frame in api:
        got = back[(frame.patch, frame.cycle)]
        assert got.force_N.tobytes() == frame.force_N.tobytes()
        assert got.timestamp == frame.timestamp and got.complete == frame.complete
    with Recording(path) as frames:
        assert sum(1 for _ in frames) == recorded.frames


def test_a_full_disk_is_one_error_and_the_file_keeps_its_whole_chunks(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        recorder_clock: _Clock) -> None:
    """The disk fills at the second write: the stop says so in one error naming the file,
    which keeps the chunk written before it (read with ``partial``: it has no footer)."""
    import os

    from canbus.tools import mcap_writer

    path = tmp_path / "full.mcap"
    recorder = Recorder(path)
    sent = _frames()
    for msg in sent[:10]:
        recorder.on_message_received(msg)
    wait_until(lambda: recorder.written == 10, what="the frames handed to the writer")
    recorder_clock.now += recorder_module.FLUSH_S
    wait_until(lambda: _stream_frames(path) == 10, what="the first chunk on disk")
    real = os.pwrite

    def full(fd: int, data: Any, offset: int) -> int:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(mcap_writer.os, "pwrite", full)
    for msg in sent[10:20]:
        recorder.on_message_received(msg)
    with pytest.raises(OSError, match=r"recording to .*full\.mcap failed: .*No space left.*"
                                      "keeps the frames written before") as info:
        recorder.stop()
    assert "\n" not in str(info.value)
    monkeypatch.setattr(mcap_writer.os, "pwrite", real)
    with Recording(path, partial=True) as recording:
        assert [_key(m) for m in recording] == [_key(m) for m in sent[:10]]
    assert [p.name for p in tmp_path.iterdir()] == ["full.mcap"]


def test_rotation_gives_mcap_files_that_each_stand_alone(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    recorder = Recorder(path, rotate_bytes=4000, placements=[Placement(1, (0.0, 0.0), 0.0,
                                                                       0.015)])
    sent = _frames()
    for msg in sent:
        recorder.on_message_received(msg)
    recorder.stop()
    assert len(recorder.files) >= 2
    got = []
    for file in recorder.files:
        with Recording(file) as recording:  # each complete and indexed
            got += [_key(m) for m in recording]
        assert [t for t, _d in decoded(file) if t == "/tf_static"] == ["/tf_static"]
    assert got == [_key(m) for m in sent]


@pytest.fixture
def recorder_clock(monkeypatch: pytest.MonkeyPatch) -> _Clock:
    clock = _Clock()
    monkeypatch.setattr(recorder_module, "time", clock)
    return clock


def test_a_sample_crosses_the_pipe_to_the_recording_process_bit_for_bit() -> None:
    from canbus.tools import sample_wire
    from canbus.tools.sample_wire import ContactFields

    rng = np.random.default_rng(3)
    contact = ContactFields(rng.normal(size=3), rng.normal(size=3), rng.normal(size=2), True,
                            0b10010001, rng.random(9) > 0.5, rng.random(9) > 0.5)
    for summary in (None, contact):
        frame = dataclasses.replace(_sample(3, 77, 9), contact=summary)
        data = sample_wire.pack(frame)
        assert len(data) == sample_wire.SIZE == 320
        got, fields = sample_wire.unpack(data)
        assert (got.patch, got.force_node, got.cycle, got.sync_counter, got.complete,
                got.published, got.timestamp) == (3, 67, 77, frame.sync_counter,
                                                  frame.complete, True, frame.timestamp)
        assert got.force_N.tobytes() == frame.force_N.tobytes()
        assert got.valid.tolist() == frame.valid.tolist()
        assert got.reason.tolist() == frame.reason.tolist()
        if summary is None:
            assert fields is None
            continue
        assert fields is not None
        for name in ("force_N", "torque_Nm", "cop_m", "contact_taxels", "taxel_slip"):
            assert getattr(fields, name).tobytes() == getattr(summary, name).tobytes(), name
        assert (fields.cop_defined, fields.state_byte) == (True, 0b10010001)
    with pytest.raises(ValueError, match="320 bytes"):
        sample_wire.unpack(bytes(10))
