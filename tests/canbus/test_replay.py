"""Replay: damaged recordings stop at the frame they name; timing, loops, any bus; CLI."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import can
import can.cli
import pytest

from canbus.tools.recorder import Recorder
from canbus.tools.recording import Recording
from canbus.tools.replay import Replayer
from skin.cli import main
from skin.errors import ConfigError, RecordingError

FILES = Path(__file__).parents[1] / "files" / "recordings"
DAMAGED = [  # file, first bad frame, what the error says
    ("truncated.log", 6, "line 6: cut short before its end of line (truncated file)"),
    ("corrupt.log", 4, "line 4: not a candump -L frame: "
                       "'(1700000000.003000) can0 181#01020G0405060708 R'"),
    ("truncated.pcap", 4, "truncated (10 of 16 bytes)"),
    ("corrupt.pcap", 3, "record of 300 bytes (original 16) is not a SocketCAN frame"),
    ("truncated.asc", 7, "the file ends here without 'End TriggerBlock' (truncated)"),
    ("corrupt.asc", 3, "line 8: DLC 8 but 4 data bytes"),
    ("truncated.blf", 251, "the file ends here, at 1869 of the 2804 bytes its header "
                           "promises (truncated)"),
    ("truncated.mcap", 5, "EOFError: the file ends before its footer (truncated: its writer "
                          "did not finish it)"),
    ("wrongschema.mcap", 1, "ValueError: topic /can/frames carries std_msgs/msg/String (cdr), "
                            "not can_msgs/msg/Frame (cdr)"),
]


def _drain(bus: can.BusABC) -> list[can.Message]:
    got = []
    while (msg := bus.recv(0)) is not None:
        got.append(msg)
    return got


@pytest.mark.parametrize(("name", "frame", "problem"), DAMAGED)
def test_damaged_recording_replays_nothing_past_the_bad_frame(name: str, frame: int,
                                                              problem: str) -> None:
    with can.Bus(interface="virtual", channel=name) as rx, \
            can.Bus(interface="virtual", channel=name) as tx:
        replayer = Replayer(tx, FILES / name, realtime=False)
        with pytest.raises(RecordingError) as info:
            replayer.run()
        got = _drain(rx)
    assert str(info.value) == f"{FILES / name}: frame {frame}: {problem}"
    assert info.value.frame == frame
    assert replayer.sent == len(got) == frame - 1
    good_name = name.replace("truncated", "good").replace("corrupt", "good")
    with Recording(FILES / good_name.replace("wrongschema", "good")) as good:
        expected = [(m.arbitration_id, bytes(m.data)) for m in good][:frame - 1]
    assert [(m.arbitration_id, bytes(m.data)) for m in got] == expected  # exact: ids, bytes


@pytest.mark.parametrize("name", ["good.log", "good.asc", "good.pcap", "good.blf", "good.mcap"])
def test_replay_sends_every_frame_in_order(name: str) -> None:
    with Recording(FILES / name) as recording:
        expected = [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in recording]
    with can.Bus(interface="virtual", channel=name) as rx, \
            can.Bus(interface="virtual", channel=name) as tx:
        result = Replayer(tx, FILES / name, realtime=False, passes=2).run()
        got = [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in _drain(rx)]
    assert got == expected * 2  # exact: COB-IDs and bytes
    assert (result.frames_sent, result.passes) == (2 * len(expected), 2)


def test_original_timing_keeps_the_intervals(tmp_path: Path) -> None:
    path = tmp_path / "slow.log"
    recorder = Recorder(path)
    for k in range(4):
        recorder.on_message_received(can.Message(timestamp=100.0 + 0.08 * k,
                                                 arbitration_id=0x80, is_extended_id=False))
    recorder.stop()
    with can.Bus(interface="virtual", channel="slow") as rx, \
            can.Bus(interface="virtual", channel="slow") as tx:
        started, started_at = time.monotonic(), time.time()
        Replayer(tx, path).run()
        took = time.monotonic() - started
        stamps = [m.timestamp for m in _drain(rx)]
    assert len(stamps) == 4
    assert took >= 0.24 - 1e-3  # any machine: MessageSync sleeps at least 3 x 80 ms
    # no frame goes out before its time on the schedule, which starts with the replay (a
    # first frame sent late may leave less than 0.24 s to the last, sent on time)
    assert stamps[-1] - started_at >= 0.24 - 1e-3  # any machine: a lower bound
    assert stamps == sorted(stamps)


def test_loop_until_stopped() -> None:
    stop = threading.Event()
    passes: list[int] = []

    def on_pass(done: int, frames: int) -> None:
        passes.append(frames)
        if done == 5:
            stop.set()

    with can.Bus(interface="virtual", channel="loop") as rx, \
            can.Bus(interface="virtual", channel="loop") as tx:
        result = Replayer(tx, FILES / "good.log", realtime=False, passes=0).run(stop, on_pass)
        assert len(_drain(rx)) == result.frames_sent == 5 * 8
    assert passes == [8] * 5


def test_unknown_suffix_or_missing_file_fail_before_the_bus_opens(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    def no_bus(*args: object, **kwargs: object) -> None:
        raise AssertionError("the bus was opened")

    monkeypatch.setattr(can.cli, "create_bus_from_namespace", no_bus)
    (tmp_path / "rec.txt").write_text("(1.0) can0 080#\n")
    assert main(["replay", str(tmp_path / "rec.txt")]) == 1
    assert "FILE: unknown recording format '.txt'" in capsys.readouterr().err
    assert main(["replay", str(tmp_path / "absent.log")]) == 1
    assert "absent.log: no such file" in capsys.readouterr().err
    (tmp_path / "empty.pcap").write_bytes(b"")
    assert main(["replay", str(tmp_path / "empty.pcap")]) == 1
    assert "not a pcap file: empty or cut short" in capsys.readouterr().err
    assert main(["replay", str(FILES / "notmcap.mcap")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"skin: error: {FILES / 'notmcap.mcap'}: not a .mcap file: not an MCAP "
                   "file (it starts b'(1700000')"]
    with can.Bus(interface="virtual", channel="x") as bus, \
            pytest.raises(ConfigError, match="unknown recording format"):
        Replayer(bus, tmp_path / "rec.txt")


def test_cli_replays_and_reports(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with can.Bus(interface="virtual", channel="cli-replay") as rx:
        code = main(["replay", str(FILES / "good.pcap"), "-i", "virtual", "-c", "cli-replay",
                     "--fast", "--loop", "2", "--json", str(tmp_path / "r.json")])
        assert code == 0
        assert len(_drain(rx)) == 12
        out = capsys.readouterr()
        assert "sent 12 frames" in out.out and "2 passes, as fast as possible" in out.out
        assert json.loads((tmp_path / "r.json").read_text())["frames_sent"] == 12

        assert main(["replay", str(FILES / "truncated.log"), "-i", "virtual", "-c", "cli-replay",
                     "--fast"]) == 1
        err = capsys.readouterr().err
        assert "(sent 5 frames before it)" in err and err.count("\n") == 1
        assert "truncated.log: frame 6: line 6: cut short" in err
        assert len(_drain(rx)) == 5


def test_fast_replay_paced_to_a_rate(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """udp_multicast has no flow control: `--rate` (by default there) caps frames/s."""
    with can.Bus(interface="virtual", channel="paced") as rx:
        started = time.monotonic()
        code = main(["replay", str(FILES / "good.log"), "-i", "virtual", "-c", "paced", "--fast",
                     "--loop", "10", "--rate", "400", "--json", str(tmp_path / "r.json")])
        took = time.monotonic() - started
        assert code == 0 and len(_drain(rx)) == 80
    assert took >= 79 / 400 - 0.002  # any machine: a slow machine only takes longer
    assert "paced to 400 frames/s" in capsys.readouterr().out
    assert json.loads((tmp_path / "r.json").read_text())["rate_fps"] == 400
    with pytest.raises(SystemExit) as refused:
        main(["replay", str(FILES / "good.log"), "--fast", "--rate", "0"])
    assert refused.value.code == 2
    assert "argument --rate: must be > 0 frames/s" in capsys.readouterr().err
