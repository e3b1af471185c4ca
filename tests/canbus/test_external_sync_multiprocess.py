"""A robot's own CANopen master in another process produces SYNC and tares a patch by SDO;
`skin run` with ``sync = "external"`` and its bus in the config's [bus] table, and
`skin sim run -i udp_multicast` without -c, find each other on the commands' default group.
"""

# mypy: disable-error-code="no-untyped-call"
from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import canopen
import numpy as np
import pytest

from canbus.od import load_od
from skin.commands.common.busargs import DEFAULT_CHANNELS

REST_SCENE = """
[scene]
name = "rest"
description = "one untouched 3-axis patch"
mode = "xyz"
rate_hz = 100.0
seed = 0

[[patches]]
node_id = 1

[[loads]]
kind = "idle"
"""


def _skin(*args: str) -> list[str]:
    return [sys.executable, "-m", "skin.cli", *args]


@pytest.mark.slow
def test_an_outside_master_drives_sync_and_tares(udp_port: int, tmp_path: Path) -> None:
    (tmp_path / "rest.toml").write_text(REST_SCENE)
    config = tmp_path / "host.toml"
    config.write_text(f"""
[host]
sync = "external"
tare_threshold_N = 0.2

[bus]
interface = "udp_multicast"
options = {{ port = {udp_port} }}

[[patches]]
node_id = 1
""")
    patches = subprocess.Popen(_skin("sim", "run", str(tmp_path / "rest.toml"), "-i",
                                     "udp_multicast", "--bus-kwargs", f"port={udp_port}"),
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    host = None
    bus = can.Bus(interface="udp_multicast", channel=DEFAULT_CHANNELS["udp_multicast"],
                  port=udp_port)
    master = canopen.Network(bus)
    master.connect()
    try:
        time.sleep(1.0)
        host = subprocess.Popen(_skin("run", str(config), "--seconds", "20", "--json",
                                      str(tmp_path / "run.json")),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        remote = master.add_node(canopen.RemoteNode(65, load_od("skin-forces", 65)))
        remote.tpdo.read(from_od=True)
        samples: list[list[int]] = []
        lock = threading.Lock()

        def on_sample(pdo: object) -> None:
            with lock:
                samples.append([v.raw for n in range(1, 8) for v in remote.tpdo[n]][:27])

        remote.tpdo[7].add_callback(on_sample)
        deadline = time.monotonic() + 15
        while remote.nmt.state != "OPERATIONAL":  # the force node starts with the host
            assert time.monotonic() < deadline, "the host's force node never came up"
            try:
                remote.nmt.wait_for_heartbeat(1.5)
            except canopen.nmt.NmtError:
                assert host.poll() is None, host.communicate()[1]
        time.sleep(1.0)
        assert samples == []  # no SYNC yet: the host waits for ours
        master.sync.start(0.01)
        deadline = time.monotonic() + 10
        while len(samples) < 50 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(samples) >= 50, host.stderr.read() if host.poll() is not None else samples
        remote.sdo.download(0x2007, 0, b"\x01")  # tare at rest
        with lock:
            samples.clear()
        time.sleep(0.5)
        with lock:
            after = np.array(samples[-20:], dtype=float)
        assert len(after) == 20 and np.abs(after).max() <= 15  # mN: near zero after the tare
        master.sync.stop()
        host.send_signal(signal.SIGINT)
        _, err = host.communicate(timeout=30)
        assert host.returncode == 0, err
        record = json.loads((tmp_path / "run.json").read_text())
        assert record["stats"]["sync_cycles"] >= 50 and record["stats"]["frames_out"] > 0
        assert record["stats"]["sync_overruns"] == 0
    finally:
        master.disconnect()
        for proc in (host, patches):
            if proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.communicate(timeout=20)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.communicate()
