"""``skin run --record run.mcap`` live, as a user runs it: ``skin sim run`` (4 patches), the
host and ``skin sniff --record beside.log`` in three processes on udp_multicast.

- SIGTERM ends the host: its MCAP is closed and indexed, and a reader independent of
  canskin (the mcap library's ROS 2 decoder) gets every sample the host published, each
  equal bit for bit to what the host's API gave (read on Zenoh), and the frames of the
  .log recorded beside it; canskin's own reader gets the same.
- kill -9: the file reads, with the mcap library and ``Recording(partial=True)``, up to its
  documented tail: a prefix of the frames the .log beside holds.
"""

from __future__ import annotations

import contextlib
import signal
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mcap_ros2", reason="the mcap extra is not installed")
pytest.importorskip("zenoh", reason="eclipse-zenoh (the zenoh extra) is not installed")

from mcap.reader import make_reader
from mcap.stream_reader import StreamReader

from canbus.offline.mcap import read_forces
from canbus.tools.recording import Recording
from tests.canbus.mcap_independent import can_frames, samples
from tests.support.rigs.children import spawn
from tests.support.rigs.mcap_run import frames_key, live_run, not_a_run_of, same_frame
from tests.support.rigs.ports import udp_bus
from tests.support.rigs.waiting import wait_until

SKIN = [sys.executable, "-m", "skin.cli"]


def _log_frames(path: Path) -> list[tuple[object, ...]]:
    with Recording(path) as recording:
        return [frames_key(m) for m in recording]


@pytest.mark.timeout(600)
def test_a_live_run_recorded_to_mcap_holds_the_host_s_samples_and_the_bus_frames(
        tmp_path: Path) -> None:
    run = live_run(tmp_path, seconds=2.0, patches=4)
    published = run.host_json["stats"]["samples"]  # type: ignore[index]
    assert run.host_json["stopped_by"] == "SIGTERM"
    assert run.host_json["recording"]["samples"] == published  # type: ignore[index]
    with run.mcap.open("rb") as file:  # closed by the SIGTERM's clean stop: indexed
        summary = make_reader(file).get_summary()
    assert summary is not None and summary.chunk_indexes and summary.statistics is not None
    # the independent reader: every sample published, bit for bit as the API gave it
    theirs = samples(run.mcap)
    assert len(theirs) == published and {p for p, _c in theirs} == {1, 2, 3, 4}
    assert len(run.api) >= 100
    for frame in run.api:
        sample = theirs[(frame.patch, frame.cycle)]
        assert sample.force_N.tobytes() == frame.force_N.astype(np.float64).tobytes()
        assert sample.valid == frame.valid.tolist()
        assert np.float64(sample.time_s).tobytes() == np.float64(frame.timestamp).tobytes()
    ours = {(f.patch, f.cycle): f for f in read_forces(str(run.mcap))}
    assert all(same_frame(f, ours[(f.patch, f.cycle)]) for f in run.api)
    # the frames: those of the .log beside, from where the host's recording began
    beside = _log_frames(run.log)
    recorded = _log_frames(run.mcap)
    assert len(recorded) > 1000
    assert not (differ := not_a_run_of(recorded, beside)), differ
    independent = can_frames(run.mcap)  # in log time order, which frames of one time share
    assert sorted(independent) == sorted((k[0], k[1], k[2], k[5]) for k in recorded
                                         if not k[3])


@pytest.mark.timeout(600)
@pytest.mark.parametrize("killed", ["host", "host and recorder"])
def test_kill_9_leaves_an_mcap_readable_up_to_its_tail(tmp_path: Path, killed: str) -> None:
    """The recording runs in a process of its own: kill -9 of the host alone ends its
    input, and it closes the file complete and indexed; kill -9 of both (the process
    group) leaves every chunk written, read to its tail by the mcap library and by
    ``Recording(partial=True)``."""
    from tests.support.rigs.mcap_run import host_toml
    from tests.support.rigs.ports import tcp_port

    channel, port = udp_bus()
    config = tmp_path / "host.toml"
    config.write_text(host_toml(channel, port, 2, tcp_port()).split("[zenoh]")[0])
    bus = ["-i", "udp_multicast", "-c", channel, "--bus-kwargs", f"port={port}"]
    log, mcap = tmp_path / "beside.log", tmp_path / "run.mcap"
    sniff = spawn([*SKIN, "sniff", *bus, "--record", str(log), "--view", "none"])
    sim = host = None
    try:
        sniff.wait_for("capturing", timeout=60)
        sim = spawn([*SKIN, "sim", "run", "indenter", "--patches", "2", *bus])
        host = spawn([*SKIN, "run", str(config), "--record", str(mcap)])
        host.wait_for("host:", timeout=60)

        def frames_on_disk() -> int:
            with Recording(mcap, partial=True) as recording:
                return sum(1 for _ in recording)

        wait_until(lambda: frames_on_disk() > 2000, what="2000 frames in run.mcap",
                   timeout=120)
        if killed == "host":
            host.stop(signal.SIGKILL)
        else:
            host.kill()  # SIGKILL to its process group: the recording process too
    finally:
        for child in (host, sim, sniff):
            if child is not None:
                child.stop(signal.SIGTERM)
    beside = _log_frames(log)
    with Recording(mcap, partial=True) as recording:
        kept = [frames_key(m) for m in recording]
        cut = recording.cut
    assert len(kept) > 2000
    assert not (differ := not_a_run_of(kept, beside)), differ
    if killed == "host":  # its recorder finished the file: strict, indexed
        assert cut is None
        with mcap.open("rb") as file:
            summary = make_reader(file).get_summary()
        assert summary is not None and summary.chunk_indexes
        assert len(list(read_forces(str(mcap)))) > 0
        return
    assert cut is not None and "footer" in str(cut)
    count = 0
    with mcap.open("rb") as file:  # the mcap library reads it as a stream, to its tail
        try:
            for record in StreamReader(file).records:
                count += type(record).__name__ == "Message"
        except Exception:  # the end of a file without its footer: the documented tail
            pass
    assert count >= len(kept)  # its frames, and the samples beside them
    samples = []
    with contextlib.suppress(EOFError):  # the samples up to the end of the last chunk
        for sample in read_forces(str(mcap)):
            samples.append(sample)
    assert samples
