"""A second node at a node-ID another node already has, in its own process on udp_multicast:
its heartbeat, OPERATIONAL (0x05) as a started node beats, every ``PERIOD_S`` until a
SIGINT or SIGTERM. Run by test_force_id_multiprocess.py.

    python -m tests.support.rigs.second_node GROUP PORT NODE_ID [PERIOD_S]

It says ``beating`` on stdout once its heartbeat has started.
"""

from __future__ import annotations

import signal
import sys

import can

OPERATIONAL = 0x05


def main(channel: str, port: int, node_id: int, period_s: float) -> None:
    stops = {signal.SIGINT, signal.SIGTERM}
    signal.pthread_sigmask(signal.SIG_BLOCK, stops)  # the sender's thread inherits it
    with can.Bus(interface="udp_multicast", channel=channel, port=port) as bus:
        heartbeat = can.Message(arbitration_id=0x700 + node_id, data=[OPERATIONAL],
                                is_extended_id=False)
        bus.send_periodic(heartbeat, period_s)
        print("beating", flush=True)
        signal.sigwait(stops)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]),
         float(sys.argv[4]) if len(sys.argv) > 4 else 1.0)
