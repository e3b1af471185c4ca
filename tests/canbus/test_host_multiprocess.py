"""The published forces through the eyes of an independent canopen master in another process."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import can
import canopen
import numpy as np

from canbus.device.patch_server import PatchServer
from canbus.device.source import ArraySource, SimulatorSource
from canbus.master.dataplane import ForceFrame
from canbus.master.host import HostManager
from canbus.master.hostconfig import HostConfig, PatchConfig
from sim import Simulator, load_scene
from skin.constants import DEFAULT_CONSTANTS
from skin.tripod import resistance_from_force
from tests.support.rigs.children import run

CYCLES = 10
NO_VALUE = -0x8000


def _z_presses(samples: int) -> np.ndarray:
    """(samples, 1, 9, 1): random normal presses up to 4 N, one sample per SYNC."""
    force = np.zeros((samples, 9, 3))
    force[..., 2] = np.random.default_rng(5).uniform(0.0, 4.0, (samples, 9))
    return resistance_from_force(force, DEFAULT_CONSTANTS)[:, None, :, :1]


def _on_the_bus(frame: ForceFrame) -> list[int]:
    """The 27 forces in mN and the 0x2005 valid bits the API's frame stands for."""
    mN = np.where(frame.valid[:, None], np.rint(frame.force_N * 1000), NO_VALUE)
    bits = sum(1 << k for k in range(9) if frame.valid[k]) | (frame.complete << 15)
    return [*mN.astype(int).reshape(27).tolist(), bits]


def test_a_canopen_master_in_another_process_reads_what_the_api_gives(
        udp_channel: str, udp_port: int, tmp_path: Path) -> None:
    patches = canopen.Network()
    patches.NOTIFIER_CYCLE = 0.05
    patches.connect(interface="udp_multicast", channel=udp_channel, port=udp_port)
    bus = can.Bus(interface="udp_multicast", channel=udp_channel, port=udp_port)
    config = HostConfig(patches=(PatchConfig(1), PatchConfig(2, mode="z", force_node=90)),
                        sync_period_ms=50.0, scan_ms=300, sdo_timeout_ms=2000)
    frames: list[ForceFrame] = []
    out = tmp_path / "master.json"
    indenter = PatchServer(patches, SimulatorSource(Simulator(load_scene("indenter"))))
    pressed = PatchServer(patches, ArraySource(_z_presses(50), (2,)))
    try:
        with indenter, pressed, HostManager(bus, config) as host:
            host.on_forces(frames.append)
            assert host.wait_operational(timeout=10.0), host.health()
            master = run([sys.executable, "-m", "tests.support.rigs.force_master",
                          udp_channel, str(udp_port), "65,90", str(CYCLES), str(out)],
                         timeout=120)
    finally:
        bus.shutdown()
        patches.disconnect()
    assert master.returncode == 0, master.stderr
    assert not host.unknown_nodes  # udp_multicast echoes the host's own frames: not nodes
    result = json.loads(out.read_text())
    assert result["nodes"]["65"] == {"identity": [0, 2, 0x00010000, 65], "source": 1,
                                     "mapping_equals_eds": True}
    assert result["nodes"]["90"]["source"] == 2
    by_cycle = {(f.force_node, f.sync_counter): f for f in frames}
    compared = {65: 0, 90: 0}
    for force_node, counter, *values in result["samples"]:
        # The master labels a sample with the last SYNC it saw. A sample published late
        # (incomplete, closed by the next SYNC; or a busy machine) follows the next SYNC.
        candidates = [by_cycle.get((force_node, c)) for c in (counter, (counter - 2) % 240 + 1)]
        assert any(f is not None and values == _on_the_bus(f) for f in candidates), (
            force_node, counter)
        compared[force_node] += 1
    assert min(compared.values()) >= CYCLES
    loaded = [f for f in frames if f.force_node == 90 and f.force_N[:, 2].max() > 1.0]
    assert loaded  # the comparison covers real forces, not only zeros
