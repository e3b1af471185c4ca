"""What udp_multicast's echo of a process's own frames costs it, and what the kernel filter
saves: 112 TPDOs every 10 ms through a canopen Network's bus (its notifier running, as in a
patch server or a host), CPU per frame sent, with the echoes handed to canopen's listener
and with them claimed (``canbus.rxfilter``: dropped in the kernel). Same bus, alternating.

Run: python -m tests.support.own_frames [ROUNDS]
"""

from __future__ import annotations

import os
import sys
import time

import canopen

from canbus.rxfilter import receive_filter
from canbus.txmessage import TxMessage

CYCLES, PERIOD_S = 200, 0.01
FRAMES = [TxMessage.data_frame(base + n, bytes(range(8)))
          for n in range(1, 17) for base in (0x180, 0x200, 0x280, 0x300, 0x380, 0x400, 0x480)]


def cpu_per_frame(network: canopen.Network) -> float:
    bus = network.bus
    assert bus is not None
    cpu0 = time.process_time()
    deadline = time.monotonic()
    for _ in range(CYCLES):
        deadline += PERIOD_S
        for msg in FRAMES:
            bus.send(msg)
        time.sleep(max(0.0, deadline - time.monotonic()))
    time.sleep(0.1)  # the last echoes are read
    return 1e6 * (time.process_time() - cpu0) / (CYCLES * len(FRAMES))


def main(rounds: int) -> None:
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.05
    network.connect(interface="udp_multicast", channel="239.74.163.253",
                    port=33000 + os.getpid() % 1000)
    assert network.bus is not None
    own, owner = receive_filter(network.bus), object()
    try:
        for k in range(rounds):
            echoed = cpu_per_frame(network)
            own.claim(owner, {m.arbitration_id for m in FRAMES})
            where = "in the kernel" if own.in_kernel else "before the listener"
            dropped = cpu_per_frame(network)
            own.release(owner)
            print(f"round {k + 1}: {echoed:.1f} us of CPU per frame sent with its echo "
                  f"received, {dropped:.1f} us with the echo dropped {where}; "
                  f"{echoed / dropped:.2f}x; load {os.getloadavg()[0]:.1f}", flush=True)
    finally:
        network.disconnect()


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 3)
