"""A second node at a force node's ID as a user meets it, each side a process of its own on
udp_multicast: 8 simulated patches (`skin sim run`), the host (`skin run`, force nodes
65..72) and, later, another process beating at patch 8's force node's ID. The host's own
frames there raise no warning, however they interleave; the other process's do."""

from __future__ import annotations

import signal
import sys
from collections import Counter
from pathlib import Path

import can

from tests.support.rigs.children import Child, spawn
from tests.support.rigs.waiting import wait_until

SKIN = [sys.executable, "-m", "skin.cli"]
HOST8 = Path(__file__).parents[2] / "examples" / "host8.toml"
FORCE_HEARTBEATS = range(0x741, 0x749)  # force nodes 65..72
WARNING = "another node transmits at the ID of patch 8's force node"


def _beats_of_every_force_node(spy: can.BusABC, seen: Counter[int], beats: int) -> bool:
    while (msg := spy.recv(timeout=0)) is not None:
        if msg.arbitration_id in FORCE_HEARTBEATS and bytes(msg.data) == b"\x05":
            seen[msg.arbitration_id] += 1
    return all(seen[cob_id] >= beats for cob_id in FORCE_HEARTBEATS)


def test_only_another_node_at_a_force_node_id_is_reported(udp_channel: str,
                                                          udp_port: int) -> None:
    bus = ["-i", "udp_multicast", "-c", udp_channel, "--bus-kwargs", f"port={udp_port}"]
    started: list[Child] = []
    with can.Bus(interface="udp_multicast", channel=udp_channel, port=udp_port) as spy:
        try:
            started.append(spawn([*SKIN, "sim", "run", "indenter", "--patches", "8", *bus]))
            host = spawn([*SKIN, "run", str(HOST8), *bus])
            started.append(host)
            for n in range(1, 9):
                host.wait_for(f"patch {n}: operational", timeout=60)
            # The force nodes' boot-ups and first heartbeats are long behind.
            seen: Counter[int] = Counter()
            wait_until(lambda: _beats_of_every_force_node(spy, seen, 2),
                       what="2 heartbeats of every force node")
            assert "another node" not in host.stderr(), host.output()
            started.append(spawn([sys.executable, "-m", "tests.support.rigs.second_node",
                                  udp_channel, str(udp_port), "72"]))
            host.wait_for(WARNING, stream="stderr", timeout=60)
        finally:
            for child in reversed(started):
                child.stop(signal.SIGTERM)
    assert host.returncode == 0, host.output()
    assert host.stderr().count("another node") == 1, host.output()
