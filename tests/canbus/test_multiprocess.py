from __future__ import annotations

import json
import sys

import canopen
import numpy as np

from canbus import codes
from canbus.device.patch_server import PatchServer
from canbus.device.source import SimulatorSource
from sim import Simulator, load_scene
from skin.constants import DEFAULT_CONSTANTS
from tests.support.rigs.children import run

SKIP, SYNCS = 4, 3  # steps 5..7 of the indenter scene press up to 2.5 N


def test_canopen_master_decodes_the_simulator_resistances(udp_channel: str,
                                                          udp_port: int) -> None:
    scene = load_scene("indenter")  # mode xyz: the default 27-value mapping is the EDS's
    simulator = Simulator(scene)
    simulator.run(SKIP)
    # The server reads one sample when it starts and one per SYNC: steps SKIP..SKIP+SYNCS.
    reference = Simulator(scene).run(SKIP + 1 + SYNCS)
    sent = reference.resistance_ohm[SKIP + 1:, 0]  # (SYNCS, 9, 3), patch node 1
    assert reference.force_N[SKIP + 1:, 0, :, 2].max() > 2.0  # the sphere is pressing
    lsb = DEFAULT_CONSTANTS.resistance_lsb_ohm
    expected = np.rint(sent / lsb).astype(np.int64).reshape(SYNCS, 27)
    np.testing.assert_allclose(sent, expected.reshape(SYNCS, 9, 3) * lsb, rtol=0, atol=1e-9)
    assert not (expected >= codes.SATURATED).any()  # real readings, no fault codes

    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05
    net.connect(interface="udp_multicast", channel=udp_channel, port=udp_port)
    try:
        with PatchServer(net, SimulatorSource(simulator)) as server:
            master = run([sys.executable, "-m", "tests.support.rigs.patch_master", udp_channel,
                          str(udp_port), str(SYNCS)], timeout=120)
    finally:
        net.disconnect()
    assert master.returncode == 0, master.stderr
    assert server.samples == 1 + SYNCS
    result = json.loads(master.stdout)
    assert result["identity"] == [0, 1, 0x00010000, 1]
    assert result["mapping_equals_eds"]
    assert result["values"] == expected.tolist()
