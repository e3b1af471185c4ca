"""Benchmark: 16 patches, 3-axis, 100 Hz SYNC on udp_multicast; prints frames and CPU share.

The server (this process) serves 16 patch nodes; the master (NMT start, SYNC producer,
TPDO counter) runs in a child process, so the CPU share printed, ``time.process_time()``
of this process over wall time while SYNCs flow, is the server's alone.

Run: python -m tests.support.patches16 [SECONDS]
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time

import can
import canopen
import numpy as np

from canbus.device.patch_server import PatchServer
from canbus.device.source import ArraySource
from skin.constants import DEFAULT_CONSTANTS
from skin.tripod import resistance_from_force

CHANNEL = "239.74.200.16"
PATCHES, TPDOS, PERIOD_S, DRAIN_S = 16, 7, 0.01, 0.3


def master(channel: str, seconds: float) -> None:
    """Child process: start the nodes, SYNC at 100 Hz for ``seconds``, count TPDOs."""
    bus = can.Bus(interface="udp_multicast", channel=channel)
    received = 0
    stop = threading.Event()

    def count() -> None:
        nonlocal received
        while not stop.is_set():
            msg = bus.recv(0.05)
            if msg is not None and 0x180 <= msg.arbitration_id < 0x500:
                received += 1

    reader = threading.Thread(target=count)
    reader.start()
    bus.send(can.Message(arbitration_id=0, data=[1, 0], is_extended_id=False))  # start all
    time.sleep(0.2)
    print("syncing", flush=True)
    task = bus.send_periodic(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False),
                             PERIOD_S)
    time.sleep(seconds)
    task.stop()
    time.sleep(DRAIN_S)
    stop.set()
    reader.join()
    bus.shutdown()
    print(json.dumps({"received": received}), flush=True)


def main(seconds: float) -> None:
    force = np.zeros((100, PATCHES, 9, 3))
    force[..., 2] = np.random.default_rng(0).uniform(0, 4, (100, PATCHES, 9))
    source = ArraySource(resistance_from_force(force, DEFAULT_CONSTANTS),
                         tuple(range(1, PATCHES + 1)))
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05
    net.connect(interface="udp_multicast", channel=CHANNEL)
    try:
        with PatchServer(net, source) as server:
            child = subprocess.Popen([sys.executable, "-m", "tests.support.patches16", "--master",
                                      CHANNEL, str(seconds)], stdout=subprocess.PIPE, text=True)
            assert child.stdout is not None
            assert child.stdout.readline().strip() == "syncing"
            cpu0, t0 = time.process_time(), time.monotonic()
            result = json.loads(child.stdout.readline())
            cpu, elapsed = time.process_time() - cpu0, time.monotonic() - t0
            child.wait(timeout=10)
            syncs, sent = server.sync_count, server.frames_sent
    finally:
        net.disconnect()
    print(f"{syncs} SYNCs in {elapsed:.1f} s, {sent} TPDOs sent (expected "
          f"{syncs * PATCHES * TPDOS}), {result['received']} received by the master "
          f"(another process); server CPU {100 * cpu / elapsed:.0f} % of one core")


if __name__ == "__main__":
    if sys.argv[1:2] == ["--master"]:
        master(sys.argv[2], float(sys.argv[3]))
    else:
        main(float(sys.argv[1]) if len(sys.argv) > 1 else 10.0)
