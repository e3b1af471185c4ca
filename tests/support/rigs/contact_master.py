"""A plain canopen master in its own process: run by test_contact_multiprocess.py.

For force node NODE it reads the contact thresholds (0x2009) by SDO, then maps the contact
PDO (TPDO 8) its own way by SDO with canopen's PdoMap (CoP x, CoP y, state, taxels in
contact, contact taxels: 8 bytes), reads the mapping back, receives ``CYCLES`` samples of
it through canopen's PdoMap callbacks, each labelled with the counter of the last SYNC
seen, and writes JSON to ``OUT``: ``{"params": [...], "mapping": [[index, sub], ...],
"samples": [[SYNC counter, CoP x, CoP y, state, count, mask], ...]}`` (raw values).
"""

from __future__ import annotations

import json
import struct
import sys
import threading
from typing import Any

import canopen
from canopen.pdo.base import PdoMap

from canbus.od import load_od

CONTACT, PARAMS = 0x2008, 0x2009
MAPPING = ((CONTACT, 7), (CONTACT, 8), (CONTACT, 11), (CONTACT, 12), (CONTACT, 13))


def main(channel: str, port: int, node_id: int, cycles: int, out: str) -> None:
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05
    net.connect(interface="udp_multicast", channel=channel, port=port)
    done = threading.Condition()
    counter = [-1]
    samples: list[list[int]] = []

    def on_sync(can_id: int, data: bytearray, timestamp: float) -> None:
        counter[0] = data[0] if data else 0

    def on_pdo(pdo: PdoMap) -> None:
        if counter[0] < 0:
            return
        with done:
            samples.append([counter[0], *(int(v.raw) for v in pdo.map)])
            done.notify()

    try:
        net.subscribe(0x80, on_sync)
        node = net.add_node(canopen.RemoteNode(node_id, load_od("skin-forces", node_id)))
        node.sdo.RESPONSE_TIMEOUT = 2.0
        params = [1e-3 * struct.unpack("<I", node.sdo.upload(PARAMS, s))[0] for s in range(1, 6)]
        contact = node.tpdo[8]
        contact.read()
        contact.clear()
        for index, sub in MAPPING:
            contact.add_variable(index, sub)
        contact.trans_type = 254
        contact.enabled = True
        contact.save()  # by SDO, CiA 301's sequence
        contact.read()  # what the node holds now
        mapping = [[v.index, v.subindex] for v in contact.map]
        contact.add_callback(on_pdo)
        with done:
            if not done.wait_for(lambda: len(samples) >= cycles, timeout=20.0):
                raise SystemExit(f"only {len(samples)} contact samples")
            result: dict[str, Any] = {"params": params, "mapping": mapping,
                                      "samples": list(samples)}
        with open(out, "w", encoding="utf-8") as handle:
            json.dump(result, handle)
    finally:
        net.disconnect()


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), sys.argv[5])
