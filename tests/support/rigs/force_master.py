"""An independent canopen master in its own process: run by test_host_multiprocess.py.

For each force node given, it reads 0x1018, 0x2001 and the TPDO configuration over SDO
into canopen's own PdoMaps (object dictionary: eds/skin-forces.eds), subscribes to the
TPDOs, labels what arrives with the counter of the last SYNC it saw, and once it has
``CYCLES`` complete samples of every force node writes them as JSON to ``OUT``:
``{"nodes": {id: {"identity": [...], "source": n, "mapping_equals_eds": bool}},
"samples": [[force node, SYNC counter, 27 forces in mN..., valid bits], ...]}``.
"""

from __future__ import annotations

import json
import sys
import threading
from typing import Any

import canopen
from canopen.pdo.base import PdoMap

from canbus.od import load_od
from canbus.pdo_codec import read_defaults, read_layouts

TPDOS = 7


def main(channel: str, port: int, force_nodes: list[int], cycles: int, out: str) -> None:
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05
    net.connect(interface="udp_multicast", channel=channel, port=port)
    done = threading.Condition()
    counter = [-1]
    partial: dict[tuple[int, int], dict[int, list[int]]] = {}
    samples: list[list[int]] = []
    nodes: dict[int, dict[str, Any]] = {}

    def on_sync(can_id: int, data: bytearray, timestamp: float) -> None:
        counter[0] = data[0] if data else 0

    def on_pdo(pdo: PdoMap) -> None:
        node_id = int(pdo.pdo_node.node.id or 0)
        if counter[0] < 0:
            return  # no SYNC seen yet: the sample cannot be labelled
        with done:
            got = partial.setdefault((node_id, counter[0]), {})
            got[int(pdo.cob_id or 0)] = [int(v.raw) for v in pdo.map]
            if len(got) == TPDOS:
                node = net[node_id]
                values = [v for n in range(1, TPDOS + 1) for v in got[node.tpdo[n].cob_id]]
                samples.append([node_id, counter[0], *values])
                done.notify()

    try:
        net.subscribe(0x80, on_sync)
        for node_id in force_nodes:
            od = load_od("skin-forces", node_id)
            node = net.add_node(canopen.RemoteNode(node_id, od))
            node.sdo.RESPONSE_TIMEOUT = 2.0
            def upload(index: int, subindex: int, sdo: Any = node.sdo) -> int:
                return int.from_bytes(sdo.upload(index, subindex), "little")

            over_sdo = read_layouts(upload, TPDOS)
            nodes[node_id] = {
                "identity": [node.sdo[0x1018][s].raw for s in range(1, 5)],
                "source": node.sdo[0x2001].raw,
                "mapping_equals_eds": over_sdo == read_layouts(read_defaults(od), TPDOS),
            }
            node.tpdo.read()  # type: ignore[no-untyped-call]  # canopen's own PdoMaps, by SDO
            for n in range(1, TPDOS + 1):
                node.tpdo[n].add_callback(on_pdo)

        def enough() -> bool:
            return all(sum(1 for s in samples if s[0] == n) >= cycles for n in force_nodes)

        with done:
            if not done.wait_for(enough, timeout=20.0):
                raise SystemExit(f"only {len(samples)} samples: {samples[:3]}")
            result = {"nodes": nodes, "samples": list(samples)}
        with open(out, "w", encoding="utf-8") as handle:
            json.dump(result, handle)
    finally:
        net.disconnect()


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), [int(n) for n in sys.argv[3].split(",")],
         int(sys.argv[4]), sys.argv[5])
