"""The timed bus as python-can sees it: the entry point, Logger and Notifier, errors."""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
import can.cli
import pytest

from canbus.framebits import frame_bits
from canbus.timed import TimedBus, TimedBusConfigError, TimedBusError, open_channels
from tests.support.rigs.waiting import wait_until

OpenBus = Callable[..., TimedBus]


def frame(can_id: int, data: bytes = b"", **kwargs: Any) -> can.Message:
    kwargs.setdefault("is_extended_id", False)
    return can.Message(arbitration_id=can_id, data=data, **kwargs)


def test_can_bus_opens_a_timed_bus_through_the_entry_point(channel: str) -> None:
    assert "timed" in can.VALID_INTERFACES  # so every -i flag of python-can accepts it
    with can.Bus(interface="timed", channel=channel, bitrate=1_000_000, fd=True,
                 data_bitrate=5_000_000) as bus, \
            can.Bus(interface="timed", channel=channel, fd=True) as other:
        assert isinstance(bus, TimedBus) and bus.protocol == can.CanProtocol.CAN_FD
        assert (bus.bitrate, bus.data_bitrate, bus.realtime) == (1_000_000, 5_000_000, True)
        assert {"interface": "timed", "channel": channel} in can.detect_available_configs(
            "timed")
        bus.send(frame(0x181, bytes(64), is_fd=True, bitrate_switch=True))
        msg = other.recv(1.0)
        assert msg is not None and msg.is_fd and len(msg.data) == 64
    assert channel not in open_channels()


def test_python_can_command_line_flags_make_a_timed_bus(channel: str) -> None:
    parser = argparse.ArgumentParser()
    can.cli.add_bus_arguments(parser)
    args = parser.parse_args(["-i", "timed", "-c", channel, "-b", "500000", "--fd",
                              "--data-bitrate", "2000000"])
    with can.cli.create_bus_from_namespace(args) as bus:
        assert isinstance(bus, TimedBus)
        assert (bus.bitrate, bus.data_bitrate) == (500_000, 2_000_000)


@pytest.mark.parametrize("suffix", [".log", ".asc"])
def test_logger_and_notifier_record_a_timed_bus(open_bus: OpenBus, suffix: str,
                                                tmp_path: Path) -> None:
    sender = open_bus(realtime=True)
    recorder = open_bus(realtime=True)
    path = tmp_path / f"trace{suffix}"
    received: list[can.Message] = []
    logger = can.Logger(path)
    notifier = can.Notifier(recorder, [logger, received.append], timeout=0.05)
    sent = [frame(0x080, b"\x01"), frame(0x181, bytes(range(8))), frame(0x701, b"\x05"),
            frame(0x1ABCDE, b"\xaa\x55", is_extended_id=True)]
    after_second = 0.0
    for msg in sent:
        sender.send(msg)
        if msg is sent[1]:
            after_second = sender.now()
    wait_until(lambda: len(received) >= len(sent), what="the frames recorded")
    notifier.stop()
    logger.stop()
    back = list(can.LogReader(path))
    assert [(m.arbitration_id, bytes(m.data)) for m in back] == [
        (m.arbitration_id, bytes(m.data)) for m in sent]
    for k in range(1, len(sent)):  # the wire's timestamps, kept (.asc writes them relative)
        assert back[k].timestamp - back[0].timestamp == pytest.approx(
            received[k].timestamp - received[0].timestamp, abs=1e-5)
    second = frame_bits(0x181, bytes(range(8))).total * 1e-6
    if after_second <= received[0].timestamp:  # sent while the first was on the wire
        assert received[1].timestamp - received[0].timestamp == pytest.approx(
            second, abs=5e-7)  # back to back
    else:  # this thread was held up longer than a frame: it started when it was sent
        assert received[1].timestamp - received[0].timestamp >= second - 5e-7


def test_channels_must_agree(open_bus: OpenBus, channel: str) -> None:
    open_bus(bitrate=500_000, fd=True, data_bitrate=2_000_000)
    with pytest.raises(TimedBusConfigError, match="runs at 500000 bit/s"):
        open_bus(bitrate=1_000_000)
    with pytest.raises(TimedBusConfigError, match="data phase at 2000000"):
        open_bus(bitrate=500_000, fd=True, data_bitrate=5_000_000)
    with pytest.raises(TimedBusConfigError, match="simulated time"):
        open_bus(bitrate=500_000, realtime=True)
    with pytest.raises(ValueError, match="bitrate"):  # also a ValueError and a python-can error
        open_bus(channel="elsewhere", bitrate=0)
    with pytest.raises(can.CanInitializationError, match="data_bitrate"):
        open_bus(channel="elsewhere", bitrate=1_000_000, data_bitrate=500_000, fd=True)
    assert open_channels() == [channel]


def test_frames_a_bus_cannot_send_are_refused_at_send(open_bus: OpenBus) -> None:
    classic = open_bus()
    with pytest.raises(can.CanOperationError, match="classic bus"):
        classic.send(frame(0x100, bytes(12), is_fd=True))
    with pytest.raises(TimedBusError, match="error frame"):
        classic.send(can.Message(is_error_frame=True))
    with pytest.raises(TimedBusError, match="out of range"):
        classic.send(can.Message(arbitration_id=0x800, is_extended_id=False, check=False))
    classic.shutdown()
    with pytest.raises(can.CanOperationError, match="closed"):
        classic.send(frame(0x100))


def test_a_full_transmit_queue_times_out(open_bus: OpenBus) -> None:
    slow = {"realtime": True, "bitrate": 1_000}  # a frame holds the wire about 0.1 s
    sender = open_bus(tx_queue_size=2, **slow)
    open_bus(**slow)
    sender.send(frame(0x100, bytes(8)))
    sender.send(frame(0x101, bytes(8)))
    started = time.monotonic()
    with pytest.raises(can.CanOperationError, match=r"transmit queue full \(2 frames\)"):
        sender.send(frame(0x102, bytes(8)), timeout=0.02)
    assert time.monotonic() - started >= 0.02  # any machine: a wait never ends early
    assert sender.node_stats().pending == 2
    sender.flush_tx_buffer()  # drops the queued frame, not the one on the wire
    assert sender.node_stats().pending == 1


def test_stats_snapshots_are_frozen_and_typed(open_bus: OpenBus) -> None:
    a, b = open_bus(node_name="host"), open_bus()
    a.send(frame(0x080, b"\x01"))
    assert b.recv(1.0) is not None
    stats = a.wire_stats()
    with pytest.raises(AttributeError):
        stats.frames = 0  # type: ignore[misc]
    assert stats.frames == 1 and stats.window_frames == 1 and stats.bits == stats.nominal_bits
    assert [n.name for n in stats.nodes] == ["host", "node1"]
    assert stats.nodes[0].sent == 1 and stats.nodes[1].received == 1
    assert 0 < stats.window_load_pct == pytest.approx(stats.load_pct)
