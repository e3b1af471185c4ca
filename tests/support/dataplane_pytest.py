"""Speed of the data plane against canopen's PdoMap callbacks (pytest-benchmark).

Run: python -m tests.support.dataplane_pytest [PYTEST-OPTIONS] (pytest with --benchmark-enable on
this file).
Each benchmark round is the whole stream: 16 patches (xyz), CYCLES SYNC cycles of 7 TPDOs
in and 7 force TPDOs out per patch; frames/s = 16 * 7 * CYCLES / round time. The stream
and both paths are skin.benchmarks.dataplane's (what `skin bench dataplane` prints).
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from typing import Any

import pytest

from decoder.protocol import Decoder
from decoder.registry import create_decoder
from skin.benchmarks.dataplane_rigs import CanopenRig, DataPlaneRig, Stream, build_stream
from skin.benchmarks.pipeline import QueuedFrames

CYCLES = 50  # 5,600 frames in, 5,600 out per round


@pytest.fixture(scope="module")
def stream() -> Stream:
    return build_stream(16, CYCLES, "xyz")


@pytest.fixture(scope="module")
def decoder() -> Decoder:
    decoder: Decoder = create_decoder("analytic")
    return decoder


@pytest.fixture
def dataplane(stream: Stream, decoder: Decoder) -> Iterator[DataPlaneRig]:
    rig = DataPlaneRig(stream, decoder)
    yield rig
    rig.close()


@pytest.fixture
def canopen_rig(stream: Stream, decoder: Decoder) -> Iterator[CanopenRig]:
    rig = CanopenRig(stream, decoder)
    yield rig
    rig.close()


def _frames_per_s(benchmark: Any, frames: int) -> None:
    stats = getattr(benchmark, "stats", None)
    if stats is not None:  # None with --benchmark-disable
        benchmark.extra_info["frames_in_per_s"] = round(frames / stats.stats.median)


@pytest.mark.benchmark(group="dataplane")
def test_bench_dataplane(benchmark: Any, dataplane: DataPlaneRig, stream: Stream) -> None:
    benchmark(dataplane.run, stream)
    _frames_per_s(benchmark, stream.frame_count)
    assert dataplane.plane.stats.incomplete_samples == 0


@pytest.mark.benchmark(group="dataplane")
def test_bench_dataplane_batch_of_one(benchmark: Any, dataplane: DataPlaneRig,
                                      stream: Stream) -> None:
    benchmark(dataplane.run, stream, per_patch=True)
    _frames_per_s(benchmark, stream.frame_count)


@pytest.mark.benchmark(group="dataplane")
def test_bench_canopen_pdomap_callbacks(benchmark: Any, canopen_rig: CanopenRig,
                                        stream: Stream) -> None:
    benchmark(canopen_rig.run, stream)
    _frames_per_s(benchmark, stream.frame_count)


@pytest.mark.benchmark(group="python-can")
def test_bench_notifier_delivery(benchmark: Any) -> None:
    """Not in the figures above: 5,600 frames (one stream's worth) from a virtual bus to a
    listener through python-can's Notifier."""
    made: list[QueuedFrames] = []

    def queued() -> tuple[tuple[QueuedFrames], dict[str, Any]]:
        made.append(QueuedFrames(5_600))
        return (made[-1],), {}

    try:  # closed here: pytest-benchmark skips teardown when benchmarks are disabled
        benchmark.pedantic(QueuedFrames.deliver, setup=queued, rounds=5)
    finally:
        for q in made:
            q.close()
    _frames_per_s(benchmark, 5_600)


def test_both_paths_send_identical_force_frames(dataplane: DataPlaneRig,
                                                canopen_rig: CanopenRig, stream: Stream) -> None:
    dataplane.run(stream)
    canopen_rig.run(stream)
    assert len(dataplane.sink.sent) == stream.frame_count
    assert dataplane.sink.sent == canopen_rig.sink.sent


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-n", "0", "--benchmark-enable", *sys.argv[1:]]))
