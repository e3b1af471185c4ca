"""A canopen master in its own process: run by test_multiprocess.py, prints JSON results."""

from __future__ import annotations

import json
import sys
import time

import canopen

from canbus.od import load_od
from canbus.pdo_codec import read_defaults, read_layouts


def main(channel: str) -> None:
    net = canopen.Network()
    net.connect(interface="udp_multicast", channel=channel)
    try:
        od = load_od("skin-patch", 1)
        node = net.add_node(canopen.RemoteNode(1, od))
        node.sdo.RESPONSE_TIMEOUT = 2.0
        identity = [node.sdo[0x1018][s].raw for s in range(1, 5)]
        over_sdo = read_layouts(lambda i, s: int.from_bytes(node.sdo.upload(i, s), "little"), 7)
        node.tpdo.read()  # canopen's own PdoMaps, read over SDO
        node.nmt.state = "OPERATIONAL"
        time.sleep(0.1)
        net.sync.transmit()
        for n in range(1, 8):
            node.tpdo[n].wait_for_reception(timeout=2.0)
        values = [int(v.raw) for n in range(1, 8) for v in node.tpdo[n].map]
        print(json.dumps({
            "identity": identity,
            "mapping_equals_eds": over_sdo == read_layouts(read_defaults(od), 7),
            "values": values,
        }))
    finally:
        net.disconnect()


if __name__ == "__main__":
    main(sys.argv[1])
