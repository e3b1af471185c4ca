"""A canopen master in its own process: run by test_multiprocess.py, prints JSON results.

Reads 0x1018 and the TPDO mapping over SDO, starts node 1 by NMT (its heartbeat, set to
50 ms, says when it is operational), sends ``SYNCS`` SYNCs
and, for each, decodes the 7 TPDOs through canopen's own PdoMaps.
"""

# mypy: disable-error-code="no-untyped-call"
from __future__ import annotations

import json
import sys
import threading

import canopen
from canopen.pdo.base import PdoMap

from canbus.od import load_od
from canbus.pdo_codec import read_defaults, read_layouts
from tests.support.rigs.waiting import wait_until

TPDOS = 7


def _heard(node: canopen.RemoteNode) -> str | None:
    """The state in the node's next heartbeat (None: none came within a second)."""
    try:
        return str(node.nmt.wait_for_heartbeat(1.0))
    except canopen.nmt.NmtError:
        return None


def main(channel: str, port: int, syncs: int) -> None:
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05  # disconnect() joins the notifier after at most one cycle
    net.connect(interface="udp_multicast", channel=channel, port=port)
    try:
        od = load_od("skin-patch", 1)
        node = net.add_node(canopen.RemoteNode(1, od))
        node.sdo.RESPONSE_TIMEOUT = 2.0
        identity = [node.sdo[0x1018][s].raw for s in range(1, 5)]
        over_sdo = read_layouts(lambda i, s: int.from_bytes(node.sdo.upload(i, s), "little"),
                                TPDOS)
        node.tpdo.read()  # canopen's own PdoMaps, read over SDO
        received: dict[int, list[int]] = {}
        arrived = threading.Condition()

        def on_pdo(pdo: PdoMap) -> None:
            with arrived:
                assert pdo.cob_id is not None
                received[pdo.cob_id] = [int(v.raw) for v in pdo.map]
                arrived.notify()

        for n in range(1, TPDOS + 1):
            node.tpdo[n].add_callback(on_pdo)
        node.sdo[0x1017].raw = 50  # heartbeats say when the start took effect
        node.nmt.state = "OPERATIONAL"
        wait_until(lambda: _heard(node) == "OPERATIONAL", what="node 1 operational")
        per_sync = []
        for _ in range(syncs):
            with arrived:
                received.clear()
                net.sync.transmit()
                if not arrived.wait_for(lambda: len(received) == TPDOS, timeout=2.0):
                    raise SystemExit(f"only TPDOs {sorted(map(hex, received))} after SYNC")
                per_sync.append([v for n in range(1, TPDOS + 1)
                                 for v in received[node.tpdo[n].cob_id]])
        print(json.dumps({
            "identity": identity,
            "mapping_equals_eds": over_sdo == read_layouts(read_defaults(od), TPDOS),
            "values": per_sync,
        }))
    finally:
        net.disconnect()


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]))
