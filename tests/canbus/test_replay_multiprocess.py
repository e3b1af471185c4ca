"""A live run on udp_multicast, recorded by `skin sniff`, replayed by `skin replay` into a
listen-only host: every sample the live host completed comes back, bit for bit.

The live host closes a cycle where the bus passed the next SYNC (the echo of its own SYNC,
docs/dataplane.md), so it takes for each cycle the frames a listen-only host reading the
same bus takes; the recording keeps the bus's order, and the replay gives it back, paced
as fast as the bus takes it and at the recording's own timing.
"""

# mypy: disable-error-code="no-untyped-call"
from __future__ import annotations

import signal
import sys
from pathlib import Path

import can
import numpy as np
import pytest

from canbus.master.dataplane import ForceFrame
from canbus.master.host import HostManager
from canbus.master.hostconfig import HostConfig, PatchConfig
from canbus.rxbuffer import enlarge_receive_buffer
from canbus.tools.recording import Recording
from tests.support.rigs.children import Child, spawn
from tests.support.rigs.ports import udp_bus
from tests.support.rigs.waiting import wait_until

PATCHES = 4
CYCLES = 300  # live cycles recorded, every patch operational
RCVBUF = 8 << 20  # the replayed frames wait in the socket while the test's process is busy


def _config(heartbeat_ms: int = 100) -> HostConfig:
    return HostConfig(patches=[PatchConfig(n) for n in range(1, PATCHES + 1)],
                      sync_period_ms=10.0, heartbeat_ms=heartbeat_ms)


def _bus(group: str, port: int) -> list[str]:
    return ["-i", "udp_multicast", "-c", group, "--bus-kwargs", f"port={port}"]


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[ForceFrame]]:
    """The live run's recording and the host's own samples (its API)."""
    folder = tmp_path_factory.mktemp("live")
    group, port = udp_bus()
    sim = spawn([sys.executable, "-m", "skin.cli", "-q", "sim", "run", "indenter",
                 "--patches", str(PATCHES), *_bus(group, port), "--seconds", "600"])
    sniff = spawn([sys.executable, "-m", "skin.cli", "sniff", *_bus(group, port), "--view",
                   "none", "--record", str(folder / "live.log"), "--seconds", "600"])
    frames: list[ForceFrame] = []
    try:
        sniff.wait_for("Ctrl-C stops", stream="stdout", timeout=60)
        with can.Bus(interface="udp_multicast", channel=group, port=port) as bus, \
                HostManager(bus, _config()) as host:
            host.on_forces(frames.append)
            assert host.wait_operational(timeout=30.0), host.health()
            first = host.stats()["sync_cycles"] + 1
            wait_until(lambda: host.stats()["sync_cycles"] > first + CYCLES,
                       what=f"{CYCLES} cycles")
        _stop(sniff)
    finally:
        sim.stop(signal.SIGTERM)
    return folder / "live.log", [f for f in frames if f.cycle >= first]


def _replay_config() -> HostConfig:
    """The live config, but a patch is lost only after 1.5 s without its heartbeat: a replay
    is paced by a process that a busy machine stalls now and then, and the heartbeats of
    the recording (100 ms) then come late, which says nothing about the cycles."""
    return _config(heartbeat_ms=1000)


def _stop(child: Child) -> None:
    assert child.stop(signal.SIGINT) == 0, child.output()


@pytest.mark.parametrize("pace", ["fast", "own-timing"])
def test_a_replay_gives_back_every_sample_the_live_host_completed(
        live: tuple[Path, list[ForceFrame]], pace: str) -> None:
    recording, frames = live
    complete = {(f.cycle, f.patch): f for f in frames if f.complete}
    assert len(complete) >= CYCLES * PATCHES // 2  # something to give back, however loaded
    with Recording(recording) as read:
        recorded = sum(1 for _ in read)
    group, port = udp_bus()
    replayed: list[ForceFrame] = []
    with can.Bus(interface="udp_multicast", channel=group, port=port) as bus, \
            HostManager(bus, _replay_config(), listen_only=True) as host:
        enlarge_receive_buffer(bus, RCVBUF)
        host.on_forces(replayed.append)
        player = spawn([sys.executable, "-m", "skin.cli", "replay", str(recording),
                        *_bus(group, port), *(["--fast"] if pace == "fast" else [])])
        assert player.wait(timeout=120) == 0, player.output()
        assert f"sent {recorded:,} frames" in player.stdout(), player.output()
        dataplane = host.dataplane

        def taken() -> int:
            s = dataplane.stats
            return s.frames_in + s.unknown_frames + s.bus_frames

        wait_until(lambda: taken() >= recorded, what="every replayed frame taken")
    by_key = {(f.cycle, f.patch): f for f in replayed}
    lost = [key for key in complete if not (key in by_key and by_key[key].complete)]
    assert not lost, f"{len(lost)} of {len(complete)} live samples not complete: {lost[:5]}"
    for key, want in complete.items():
        got = by_key[key]
        np.testing.assert_array_equal(got.force_N, want.force_N, err_msg=str(key))
        np.testing.assert_array_equal(got.valid, want.valid, err_msg=str(key))
