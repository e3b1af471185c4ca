"""A bare python-can receiver on a udp_multicast bus: the floor of the transport's cost.

    python -m skin.benchmarks.bare_receiver GROUP PORT FORCE_COB_IDS PATCH_COB_IDS

It takes every frame with ``bus.recv`` in one thread and counts it; nothing else, apart
from the set lookups that time the host's answer as an independent listener sees it:
the kernel's receive stamps of each SYNC (0x080), of the cycle's last patch PDO and of its
last force PDO (the COB-IDs given, comma-separated hex). SIGUSR1 opens and then closes the
measured window; at each, one JSON line on stdout: frames so far, this process's CPU
time, and (at the close) the window's delays in ms: SYNC -> last force PDO, and last
patch PDO -> last force PDO (the host's own part). SIGTERM ends it.
"""

from __future__ import annotations

import json
import signal
import sys
import time

import can

SYNC_COB_ID = 0x080


def main() -> None:
    group, port = sys.argv[1], int(sys.argv[2])
    force, patch = (frozenset(int(c, 16) for c in text.split(",") if c)
                    for text in sys.argv[3:5])
    state = {"frames": 0, "window": 0, "running": True}
    delays: list[float] = []
    host_part: list[float] = []

    def mark(_signum: int, _frame: object) -> None:
        state["window"] += 1
        out: dict[str, object] = {"frames": state["frames"], "cpu_s": time.process_time(),
                                  "time": time.time()}
        if state["window"] == 2:
            out["sync_to_last_force_pdo_ms"] = delays
            out["last_patch_pdo_to_last_force_pdo_ms"] = host_part
        print(json.dumps(out), flush=True)

    def stop(_signum: int, _frame: object) -> None:
        state["running"] = False

    signal.signal(signal.SIGUSR1, mark)
    signal.signal(signal.SIGTERM, stop)
    with can.Bus(interface="udp_multicast", channel=group, port=port) as bus:
        print(json.dumps({"ready": True}), flush=True)
        frames = 0
        sync_t = last_force = last_patch = 0.0
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
                    if last_force > last_patch > sync_t:
                        host_part.append(1e3 * (last_force - last_patch))
                sync_t = msg.timestamp
            elif cob in force:
                last_force = msg.timestamp
            elif cob in patch:
                last_patch = msg.timestamp


if __name__ == "__main__":
    main()
