"""Zenoh never costs the CAN side its samples: with a reader whose callback stalls and a TCP
connection to the host's Zenoh port that never reads, the host on udp_multicast keeps its
steady-state samples complete (publishing never blocks the data plane; docs/zenoh.md)."""

from __future__ import annotations

import json
import signal
import socket
import sys
from pathlib import Path

import pytest

from tests.support.rigs.children import spawn
from tests.support.rigs.ports import tcp_port

pytest.importorskip("zenoh", reason="eclipse-zenoh (the zenoh extra) is not installed")

SKIN = [sys.executable, "-m", "skin.cli"]
PATCHES = 4
SECONDS = 8
STALL_S = 1.0  # the reader's callback holds Zenoh's receiving thread this long per sample
BAR_PCT = 99.5  # 99.9 on an idle machine (docs/zenoh.md); the suite runs beside itself


def test_a_stalled_reader_and_a_connection_that_never_reads_cost_the_can_side_nothing(
        tmp_path: Path, udp_channel: str, udp_port: int) -> None:
    port = tcp_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    config = tmp_path / "host.toml"
    config.write_text("[host]\nheartbeat_ms = 500\n[bus]\ninterface = \"udp_multicast\"\n"
                      f"channel = \"{udp_channel}\"\noptions = {{ port = {udp_port} }}\n"
                      + "".join(f"[[patches]]\nnode_id = {n}\n" for n in range(1, PATCHES + 1))
                      + f"[zenoh]\nhost = \"stalled\"\nlisten = [\"{endpoint}\"]\n")
    out = tmp_path / "run.json"
    sim = spawn([*SKIN, "-q", "sim", "run", "indenter", "--patches", str(PATCHES), "-i",
                 "udp_multicast", "-c", udp_channel, "--bus-kwargs", f"port={udp_port}"])
    host = spawn([*SKIN, "run", str(config), "--seconds", str(SECONDS), "--json", str(out)])
    try:
        host.wait_for("zenoh: publishing", timeout=60)
        reader = spawn([sys.executable, "-m", "tests.support.rigs.zenoh_slow_reader", endpoint,
                        str(STALL_S)])
        reader.wait_for("got 1", timeout=60)  # it holds Zenoh's thread from here on
        with socket.create_connection(("127.0.0.1", port)) as deaf:  # connects, never reads
            deaf.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            assert host.wait(timeout=SECONDS + 60) == 0, host.output()
        reader.stop(signal.SIGTERM)
    finally:
        sim.stop(signal.SIGTERM)
    record = json.loads(out.read_text())
    stats = record["stats"]
    assert stats["steady_samples"] >= PATCHES * 100  # a second's worth at least
    assert record["steady_complete_pct"] >= BAR_PCT, (stats, record["zenoh"])
    assert record["zenoh"]["sent"] > 0  # it did publish
