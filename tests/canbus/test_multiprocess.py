from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import canopen
import numpy as np

from canbus import codes
from canbus.patch_server import PatchServer
from canbus.source import ArraySource
from skin.constants import DEFAULT_CONSTANTS
from skin.tripod import resistance_from_force


def test_canopen_master_in_another_process(udp_channel: str) -> None:
    rng = np.random.default_rng(7)
    force = np.zeros((1, 1, 9, 3))
    force[..., :2] = rng.uniform(-0.5, 0.5, (9, 2))
    force[..., 2] = rng.uniform(0.0, 4.0, 9)
    resistance = resistance_from_force(force, DEFAULT_CONSTANTS)
    expected = codes.resistance_to_code(resistance[0, 0], DEFAULT_CONSTANTS.resistance_lsb_ohm)
    net = canopen.Network()
    net.connect(interface="udp_multicast", channel=udp_channel)
    try:
        with PatchServer(net, ArraySource(resistance, (1,))):
            run = subprocess.run([sys.executable, str(Path(__file__).with_name("master_script.py")),
                                  udp_channel], capture_output=True, text=True, timeout=30)
    finally:
        net.disconnect()
    assert run.returncode == 0, run.stderr
    result = json.loads(run.stdout)
    assert result["identity"] == [0, 1, 0x00010000, 1]
    assert result["mapping_equals_eds"]
    assert result["values"] == expected.reshape(-1).tolist()
