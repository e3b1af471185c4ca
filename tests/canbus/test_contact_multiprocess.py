"""The contact PDO through the eyes of a plain canopen master in another process."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import can
import canopen
import numpy as np
import pytest

from canbus.device.patch_server import PatchServer
from canbus.device.source import SimulatorSource
from canbus.master.dataplane import ForceFrame
from canbus.master.host import HostManager
from canbus.master.hostconfig import HostConfig, PatchConfig
from sim import Simulator, load_scene
from skin.contact import ContactParams
from skin.contact_state import ContactSummary
from tests.support.rigs import children

CYCLES = 40
NO_VALUE = -0x8000
PARAMS = ContactParams(taxel_contact_N=0.1, onset_N=0.25, release_N=0.15, friction=0.6,
                       near_slip_margin=0.25)


def _expected(c: ContactSummary) -> list[int]:
    """CoP x, y in 0.01 mm, the state byte, taxels in contact, the contact mask."""
    cop = [int(np.rint(v * 1e5)) if c.cop_defined else NO_VALUE for v in c.cop_m]
    flags = (c.in_contact, c.onset, c.release, c.near_slip, c.slipping, c.slip_onset,
             c.partial, c.unknown)
    state = sum(1 << k for k, on in enumerate(flags) if on)
    mask = sum(1 << k for k in range(9) if c.contact_taxels[k])
    return [*cop, state, c.taxels_in_contact, mask]


def test_a_canopen_master_maps_the_contact_pdo_and_reads_what_the_api_gives(
        udp_channel: str, udp_port: int, tmp_path: Path) -> None:
    patches = canopen.Network()
    patches.NOTIFIER_CYCLE = 0.05
    patches.connect(interface="udp_multicast", channel=udp_channel, port=udp_port)
    bus = can.Bus(interface="udp_multicast", channel=udp_channel, port=udp_port)
    config = HostConfig(patches=(PatchConfig(1, position_m=(0.1, 0.2), orientation_deg=30.0,
                                             contact=PARAMS),),
                        sync_period_ms=25.0, scan_ms=300, sdo_timeout_ms=2000)
    frames: list[ForceFrame] = []
    out = tmp_path / "master.json"
    server = PatchServer(patches, SimulatorSource(Simulator(load_scene("indenter"), seed=4)))
    try:
        with server, HostManager(bus, config) as host:
            host.on_forces(frames.append)
            assert host.wait_operational(timeout=10.0), host.health()
            run = children.run(
                [sys.executable, "-m", "tests.support.rigs.contact_master",
                 udp_channel, str(udp_port), "65", str(CYCLES), str(out)],
                cwd=Path(__file__).resolve().parents[2], timeout=60)
    finally:
        bus.shutdown()
        patches.disconnect()
    assert run.returncode == 0, run.stderr
    result = json.loads(out.read_text())
    assert result["params"] == pytest.approx([0.1, 0.25, 0.15, 0.6, 0.25], rel=1e-6)
    assert result["mapping"] == [[0x2008, 7], [0x2008, 8], [0x2008, 11], [0x2008, 12],
                                 [0x2008, 13]]
    by_cycle = {f.sync_counter: f for f in frames}
    for counter, *values in result["samples"]:
        candidates = [by_cycle.get(c) for c in (counter, (counter - 2) % 240 + 1)]
        assert any(f is not None and f.contact is not None and values == _expected(f.contact)
                   for f in candidates), (counter, values)
    touched = [s for s in result["samples"] if s[1] != NO_VALUE]
    assert len(touched) >= CYCLES // 4  # the indenter pressed: real CoPs were compared
    assert any(s[3] & 1 for s in result["samples"])  # ... and contact states
