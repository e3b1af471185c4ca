"""Recorder: every format read back frame for frame; can-utils reads our .log; the file."""

from __future__ import annotations

import shutil
from pathlib import Path

import can
import pytest

from canbus.rxbuffer import enlarge_receive_buffer
from canbus.tools.recorder import (
    CandumpLogWriter,
    Recorder,
    log_channel_name,
    recording_format,
)
from canbus.tools.recording import Recording
from skin.errors import ConfigError
from tests.support.rigs import children

T0 = 1_700_000_000.0


def _frames() -> list[can.Message]:
    """SYNC, TPDOs, SDO, heartbeat, a 29-bit frame, a remote frame: what a bus carries."""
    frames = [
        can.Message(arbitration_id=0x080, data=b"\x07", is_extended_id=False),
        can.Message(arbitration_id=0x181, data=bytes(range(8)), is_extended_id=False),
        can.Message(arbitration_id=0x401, data=b"\x20\x4e\x7c\x6e\xff\xff",
                    is_extended_id=False),
        can.Message(arbitration_id=0x601, data=b"\x40\x18\x10\x01\0\0\0\0",
                    is_extended_id=False),
        can.Message(arbitration_id=0x701, data=b"\x05", is_extended_id=False),
        can.Message(arbitration_id=0x1ABCDE, data=b"\xde\xad", is_extended_id=True),
        can.Message(arbitration_id=0x123, is_remote_frame=True, dlc=4, is_extended_id=False),
        can.Message(arbitration_id=0x000, data=b"\x01\x00", is_extended_id=False),
    ]
    for k, msg in enumerate(frames):
        msg.timestamp = T0 + 0.001234 * k
        msg.channel = "can0"
    return frames


def _key(msg: can.Message) -> tuple[object, ...]:
    return (msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, msg.dlc,
            bytes(msg.data))


def _relative(messages: list[can.Message]) -> list[float]:
    return [m.timestamp - messages[0].timestamp for m in messages]


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf", ".pcap"])
def test_every_format_reads_back_frame_for_frame(tmp_path: Path, suffix: str) -> None:
    sent = _frames()
    recorder = Recorder(tmp_path / f"rec{suffix}")
    for msg in sent:
        recorder.on_message_received(msg)
    recorder.stop()
    assert recorder.saved == tmp_path / f"rec{suffix}"
    with can.LogReader(recorder.saved) if suffix != ".pcap" else Recording(recorder.saved) \
            as reader:  # python-can's own reader for its formats
        got = list(reader)
    assert [_key(m) for m in got] == [_key(m) for m in sent]
    assert _relative(got) == pytest.approx(_relative(sent), abs=1.5e-6)
    if suffix in (".log", ".pcap"):  # absolute times kept to the microsecond
        assert [m.timestamp for m in got] == pytest.approx([m.timestamp for m in sent],
                                                           abs=1e-6, rel=0)


@pytest.mark.skipif(shutil.which("log2asc") is None,
                    reason="can-utils' log2asc is not installed (apt install can-utils)")
def test_can_utils_log2asc_reads_our_log(tmp_path: Path) -> None:
    sent = _frames()
    recorder = Recorder(tmp_path / "rec.log")
    for msg in sent:
        recorder.on_message_received(msg)
    recorder.stop()
    out = tmp_path / "rec.asc"
    run = children.run(["log2asc", "-I", str(tmp_path / "rec.log"), "-O", str(out), "can0"],
                       timeout=60)
    assert run.returncode == 0, run.stderr
    with can.ASCReader(out) as reader:  # log2asc's output read by python-can
        got = list(reader)
    assert [_key(m) for m in got] == [_key(m) for m in sent]
    assert _relative(got) == pytest.approx(_relative(sent), abs=1.5e-6)
    assert [m.is_rx for m in got] == [m.is_rx for m in sent]


def _interfaces(path: Path) -> set[str]:
    return {line.split()[1] for line in path.read_text().splitlines()}


def test_a_log_names_every_frame_with_one_interface_name(tmp_path: Path) -> None:
    """udp_multicast frames carry no channel (python-can writes "vcan0"), virtual ones their
    channel's name: a .log gets one interface name, ``can0`` unless told otherwise."""
    frames = _frames()
    frames[0].channel, frames[1].channel = None, "skin"
    for name, expected in ((None, "can0"), ("vcan1", "vcan1")):
        path = tmp_path / f"{name}.log"
        recorder = Recorder(path, channel=name)
        for msg in frames:
            recorder.on_message_received(msg)
        recorder.stop()
        assert _interfaces(path) == {expected}
    assert frames[1].channel == "skin"  # the listeners' shared message is left as it was
    with pytest.raises(ConfigError, match="not an interface name"):
        Recorder(tmp_path / "bad.log", channel="239.0.0.1")  # no socket: a name checked


def test_log_channel_name_is_the_bus_channel_when_it_can_name_an_interface() -> None:
    assert log_channel_name("skin0") == "skin0"
    assert log_channel_name("239.74.163.2") == "can0"  # no socket: udp_multicast's group
    assert log_channel_name(None) == "can0"


@pytest.mark.skipif(shutil.which("log2asc") is None,
                    reason="can-utils' log2asc is not installed (apt install can-utils)")
def test_the_readmes_log2asc_line_reads_a_udp_multicast_recording(tmp_path: Path) -> None:
    sent = _frames()
    for msg in sent:
        msg.channel = None  # as udp_multicast delivers them
    group = "239.74.163.2"  # no socket: a channel name
    recorder = Recorder(tmp_path / "run.log", channel=log_channel_name(group))
    for msg in sent:
        recorder.on_message_received(msg)
    recorder.stop()
    run = children.run(["log2asc", "-I", "run.log", "can0"], cwd=tmp_path, timeout=60)
    assert run.returncode == 0, run.stderr
    assert sum(" Rx " in line or " Tx " in line for line in run.stdout.splitlines()) == len(sent)


def test_the_file_is_there_from_the_start_under_its_own_name(tmp_path: Path) -> None:
    target = tmp_path / "rec.pcap"
    recorder = Recorder(target)
    assert [p.name for p in tmp_path.iterdir()] == ["rec.pcap"]  # no hidden temporary file
    for msg in _frames():
        recorder.on_message_received(msg)
    recorder.stop()
    recorder.stop()  # idempotent: python-can's Notifier.stop() calls it too
    assert recorder.written == recorder.received == len(_frames())
    assert recorder.saved == target and recorder.files == [target]
    assert [p.name for p in tmp_path.iterdir()] == ["rec.pcap"]
    assert target.stat().st_mode & 0o644 == 0o644  # the mode open() would give, not 0600


def test_a_failing_writer_is_reported_and_the_file_keeps_what_came_before(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    real = CandumpLogWriter.on_message_received
    calls = [0]

    def disk_full_at_the_fourth(self: CandumpLogWriter, msg: can.Message) -> None:
        calls[0] += 1
        if calls[0] == 4:
            raise OSError(28, "No space left on device")
        real(self, msg)

    monkeypatch.setattr(CandumpLogWriter, "on_message_received", disk_full_at_the_fourth)
    failing = Recorder(tmp_path / "full.log")
    for msg in _frames():
        failing.on_message_received(msg)
    with pytest.raises(OSError, match=r"recording to .*full\.log failed: .*No space left.*"
                                      "keeps the frames written before"):
        failing.stop()
    with Recording(tmp_path / "full.log") as recording:
        assert [_key(m) for m in recording] == [_key(m) for m in _frames()[:3]]


def test_unknown_suffix_is_refused_before_any_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"--record: unknown recording format '\.txt'"):
        Recorder(tmp_path / "rec.txt")
    with pytest.raises(ConfigError, match=r"'\(no suffix\)'"):
        recording_format(tmp_path / "rec")
    assert recording_format("X.PCAP") == ".pcap"
    assert list(tmp_path.iterdir()) == []


def test_receive_buffer(udp_channel: str, udp_port: int) -> None:
    with can.Bus(interface="virtual", channel="rcvbuf") as bus:
        assert enlarge_receive_buffer(bus, 1 << 20) is None  # not a socket
    with can.Bus(interface="udp_multicast", channel=udp_channel, port=udp_port) as bus:
        default = enlarge_receive_buffer(bus, 4096)
        granted = enlarge_receive_buffer(bus, 1 << 20)
        assert default is not None and granted is not None and granted > default
