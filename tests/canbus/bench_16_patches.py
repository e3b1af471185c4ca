"""Benchmark: 16 patches, 3-axis, 100 Hz SYNC on udp_multicast; prints frames and CPU share.

Run: /work/venv/bin/python tests/canbus/bench_16_patches.py [SECONDS]
"""

from __future__ import annotations

import os
import sys
import threading
import time

import can
import canopen
import numpy as np

from canbus.patch_server import PatchServer
from canbus.source import ArraySource
from skin.constants import DEFAULT_CONSTANTS
from skin.tripod import resistance_from_force


def main(seconds: float) -> None:
    channel = "239.74.200.16"
    force = np.zeros((100, 16, 9, 3))
    force[..., 2] = np.random.default_rng(0).uniform(0, 4, (100, 16, 9))
    source = ArraySource(resistance_from_force(force, DEFAULT_CONSTANTS), tuple(range(1, 17)))
    net = canopen.Network()
    net.connect(interface="udp_multicast", channel=channel)
    master = can.Bus(interface="udp_multicast", channel=channel)
    received = 0
    stop = threading.Event()

    def count() -> None:
        nonlocal received
        while not stop.is_set():
            msg = master.recv(0.1)
            if msg is not None and 0x180 <= msg.arbitration_id < 0x500:
                received += 1

    reader = threading.Thread(target=count)
    reader.start()
    with PatchServer(net, source) as server:
        for n in range(1, 17):
            master.send(can.Message(arbitration_id=0, data=[1, n], is_extended_id=False))
        time.sleep(0.2)
        cpu0, t0 = os.times(), time.monotonic()
        task = master.send_periodic(can.Message(arbitration_id=0x80, data=b"",
                                                is_extended_id=False), 0.01)
        time.sleep(seconds)
        task.stop()
        time.sleep(0.2)
        elapsed, cpu1 = time.monotonic() - t0, os.times()
        syncs = server.sync_count
    stop.set()
    reader.join()
    master.shutdown()
    net.disconnect()
    cpu = (cpu1.user - cpu0.user + cpu1.system - cpu0.system) / elapsed
    print(f"{syncs} SYNCs in {elapsed:.1f} s, {server.frames_sent} TPDOs sent "
          f"(expected {syncs * 16 * 7}), {received} received by the master; "
          f"process CPU (server + master counter) {100 * cpu:.0f} % of one core")


if __name__ == "__main__":
    main(float(sys.argv[1]) if len(sys.argv) > 1 else 10.0)
