"""``skin bench dataplane``'s whole path: every frame taken, every sample complete, and its
receive side timed on its own threads' CPU clocks, the sender in the same process apart."""

from __future__ import annotations

import threading

import pytest

from decoder.registry import create_decoder
from skin.benchmarks.dataplane_rigs import build_stream
from skin.benchmarks.pipeline import ReceiveSideClock, pipeline_rate
from skin.errors import BusError


def test_the_whole_path_takes_every_frame_and_times_its_receive_side() -> None:
    stream = build_stream(4, 30, "xyz")
    figures = pipeline_rate(stream, create_decoder("analytic"))
    assert figures["complete"] == 1.0
    assert figures["frames_per_s"] > 0
    assert figures["receive_frames_per_cpu_s"] > 0


def test_the_receive_clock_counts_only_its_threads() -> None:
    """A thread that waits while another works: its own CPU clock stays where it was."""
    release = threading.Event()
    idle = threading.Thread(target=release.wait, name="idle receive side", daemon=True)
    idle.start()
    try:
        clock = ReceiveSideClock(["idle receive side"])
        total = sum(k * k for k in range(2_000_000))  # the caller's own work
        assert total > 0
        assert clock.seconds() < 0.05  # any machine: the waiting thread's own CPU clock
    finally:
        release.set()
        idle.join()


def test_a_thread_not_running_is_named() -> None:
    with pytest.raises(BusError, match="no thread named"):
        ReceiveSideClock(["no such thread"])
