"""A bare python-can receiver on a udp_multicast bus: the floor of the transport's cost.

    python -m bench.bare_receiver GROUP PORT FORCE_COB_IDS

It takes every frame with ``bus.recv`` in one thread and counts it; nothing else, apart
from the one comparison that times the host's answer as an independent listener sees it:
the kernel's receive stamps of each SYNC (0x080) and of the last force PDO after it (the
COB-IDs given, comma-separated hex). SIGUSR1 opens and then closes the measured window;
at each, one JSON line on stdout: frames so far, this process's CPU time, and (at the
close) the window's SYNC -> last force PDO delays in ms. SIGTERM ends it.
"""

from __future__ import annotations

import json
import signal
import sys
import time

import can

SYNC_COB_ID = 0x080


def main() -> None:
    group, port, force_text = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    force = frozenset(int(c, 16) for c in force_text.split(",") if c)
    state = {"frames": 0, "window": 0, "running": True}
    delays: list[float] = []

    def mark(_signum: int, _frame: object) -> None:
        state["window"] += 1
        out: dict[str, object] = {"frames": state["frames"], "cpu_s": time.process_time(),
                                  "time": time.time()}
        if state["window"] == 2:
            out["sync_to_last_force_pdo_ms"] = delays
        print(json.dumps(out), flush=True)

    def stop(_signum: int, _frame: object) -> None:
        state["running"] = False

    signal.signal(signal.SIGUSR1, mark)
    signal.signal(signal.SIGTERM, stop)
    with can.Bus(interface="udp_multicast", channel=group, port=port) as bus:
        print(json.dumps({"ready": True}), flush=True)
        frames = 0
        sync_t = last_force = 0.0
        while state["running"]:
            msg = bus.recv(0.2)
            if msg is None:
                continue
            frames += 1
            state["frames"] = frames
            cob = msg.arbitration_id
            if cob == SYNC_COB_ID:
                if state["window"] == 1 and last_force > sync_t > 0:
                    delays.append(1e3 * (last_force - sync_t))
                sync_t = msg.timestamp
            elif cob in force:
                last_force = msg.timestamp


if __name__ == "__main__":
    main()
