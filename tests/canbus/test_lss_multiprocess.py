"""From the box to the bus, across processes on udp_multicast (loopback): canopen's
``LssMaster.fast_scan()`` finds the 8 identical patches of ``skin sim run --unconfigured``;
the host gives them node-IDs from its serial table, stores them and runs them; a restart of
``skin sim run`` with the same state dir boots them with those node-IDs; a calibrated R0
written by ``skin calibrate --write-node --store`` survives a restart too."""

# mypy: disable-error-code="no-untyped-call"
from __future__ import annotations

import argparse
import queue
import signal
import struct
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import can
import canopen
import numpy as np
import pytest

from canbus.master.host import HostManager
from canbus.master.hostconfig import load_host_config
from canbus.od import load_od
from skin.commands.calibrate.output import write_rest_to_node
from tests.support.rigs.children import spawn

PATCHES = 8
SERIAL_BASE = 0x5100_0000
SERIALS = [SERIAL_BASE + k for k in range(1, PATCHES + 1)]
START_S = 60.0


@contextmanager
def sim_run(channel: str, port: int, state_dir: Path, *more: str) -> Iterator[list[str]]:
    """``skin sim run idle --patches 8`` in its own process until the block ends (SIGTERM);
    yields its output lines so far, once it said it serves."""
    proc = spawn([sys.executable, "-m", "skin.cli", "sim", "run", "idle", "--patches",
                  str(PATCHES), "--serial-base", hex(SERIAL_BASE), "--state-dir",
                  str(state_dir), *more, "-i", "udp_multicast", "-c", channel, "--bus-kwargs",
                  f"port={port}"])
    try:
        proc.wait_for("Ctrl-C stops", timeout=START_S)
        yield proc.stdout().splitlines()
    finally:
        code = proc.stop(signal.SIGTERM)
    assert code == 0, proc.output()


@contextmanager
def master(channel: str, port: int) -> Iterator[canopen.Network]:
    network = canopen.Network(can.Bus(interface="udp_multicast", channel=channel, port=port))
    network.NOTIFIER_CYCLE = 0.05
    network.connect()
    try:
        yield network
    finally:
        if network.bus is not None:
            network.disconnect()


class Boots:
    """Boot-up messages (0x701..0x77F, one byte 0) seen on a network."""

    def __init__(self, network: canopen.Network) -> None:
        self.seen: queue.Queue[int] = queue.Queue()
        for node_id in range(1, 128):
            network.subscribe(0x700 + node_id, self._on)

    def _on(self, cob_id: int, data: bytearray, timestamp: float) -> None:
        if bytes(data) == b"\x00":
            self.seen.put(cob_id - 0x700)

    def wait(self, node_ids: set[int], timeout: float = 30.0) -> set[int]:
        got: set[int] = set()
        end = time.monotonic() + timeout
        while not node_ids <= got and (left := end - time.monotonic()) > 0:
            try:
                got.add(self.seen.get(timeout=left))
            except queue.Empty:
                break
        return got


def _serials_by_sdo(network: canopen.Network, node_ids: list[int]) -> dict[int, int]:
    out = {}
    for node_id in node_ids:
        node = network.add_node(canopen.RemoteNode(node_id, load_od("skin-patch", node_id)))
        node.sdo.RESPONSE_TIMEOUT = 2.0
        out[node_id] = struct.unpack("<I", node.sdo.upload(0x1018, 4))[0]
    return out


@pytest.mark.slow
def test_fast_scan_finds_all_eight_unconfigured_patches(udp_channel: str, udp_port: int,
                                                        tmp_path: Path) -> None:
    with sim_run(udp_channel, udp_port, tmp_path, "--unconfigured") as lines, \
            master(udp_channel, udp_port) as network:
        assert any("8 patches wait for LSS" in line for line in lines)
        boots = Boots(network)
        found: list[list[int]] = []
        deadline = time.monotonic() + 180.0
        while len(found) < PATCHES and time.monotonic() < deadline:
            # A scan fails when an answer came after canopen's 0.5 s (a busy machine): the
            # patches are left as they were, so scan again until the deadline.
            ok, identity = network.lss.fast_scan()
            if not ok:
                continue
            found.append(identity)
            network.lss.configure_node_id(10 + len(found) - 1)
            network.lss.send_switch_state_global(network.lss.WAITING_STATE)
        ok, _ = network.lss.fast_scan()
        assert not ok, "a ninth patch answered the fastscan"
        assert sorted(i[3] for i in found) == SERIALS  # each once, in ascending order
        assert found == sorted(found)
        assert all(i[:3] == [0, 1, 0x0001_0000] for i in found)
        ids = set(range(10, 10 + PATCHES))
        assert boots.wait(ids) == ids
        # the fastscan order is the serials' order: node 10 + k has the k-th serial
        assert _serials_by_sdo(network, sorted(ids)) == \
            {10 + k: serial for k, serial in enumerate(SERIALS)}


@pytest.mark.slow
def test_the_host_assigns_from_its_serial_table_and_stored_ids_survive_a_restart(
        udp_channel: str, udp_port: int, tmp_path: Path) -> None:
    table = {serial: 20 + (PATCHES - k) for k, serial in enumerate(SERIALS)}  # reversed
    config = tmp_path / "host.toml"
    config.write_text("\n".join(
        ["[host]", "lss_store = true", "scan_ms = 300", "heartbeat_ms = 200",
         "[bus]", 'interface = "udp_multicast"', f'channel = "{udp_channel}"',
         f"options = {{ port = {udp_port} }}"] +
        [f"[[patches]]\nnode_id = {node_id}\nserial = {serial:#x}\nforce_node = {node_id + 64}"
         for serial, node_id in table.items()]) + "\n")
    state = tmp_path / "state"
    with sim_run(udp_channel, udp_port, state, "--unconfigured"):
        bus = can.Bus(interface="udp_multicast", channel=udp_channel, port=udp_port)
        try:
            with HostManager(bus, load_host_config(config)) as host:
                assert sorted((a.serial, a.node_id) for a in host.lss_assignments) == \
                    sorted(table.items())
                assert all(a.stored for a in host.lss_assignments)
                assert host.wait_operational(timeout=60.0)
                frames = host.frames(timeout=10.0)
                seen = set()
                for frame in frames:  # every patch decodes
                    seen.add(frame.patch)
                    if seen == set(table.values()):
                        break
                assert seen == set(table.values())
        finally:
            bus.shutdown()
    # a power cycle: the same state dir, the same --unconfigured command line
    with sim_run(udp_channel, udp_port, state, "--unconfigured") as lines, \
            master(udp_channel, udp_port) as network:
        assert not any("wait for LSS" in line for line in lines)
        boots = Boots(network)
        network.nmt.send_command(0x82)  # reset communication: each boots again
        assert boots.wait(set(table.values())) == set(table.values())
        assert _serials_by_sdo(network, sorted(table.values())) == \
            {node_id: serial for serial, node_id in table.items()}
        network.disconnect()
        bus = can.Bus(interface="udp_multicast", channel=udp_channel, port=udp_port)
        try:  # the host finds every patch at its stored node-ID: no LSS needed
            with HostManager(bus, load_host_config(config)) as host:
                assert host.lss_assignments == []
                assert host.wait_operational(timeout=60.0)
        finally:
            bus.shutdown()


@pytest.mark.slow
def test_a_stored_calibrated_rest_survives_a_restart(udp_channel: str, udp_port: int,
                                                     tmp_path: Path) -> None:
    rest = np.round(np.tile([1012.345, 1433.21, 1431.987], (9, 1)), 3)
    args = argparse.Namespace(interface="udp_multicast", channel=udp_channel,
                              bus_kwargs={"port": udp_port}, sdo_timeout=2.0, store=True)
    with sim_run(udp_channel, udp_port, tmp_path):
        assert write_rest_to_node(args, 3, rest) == 27
    with sim_run(udp_channel, udp_port, tmp_path), master(udp_channel, udp_port) as network:
        node = network.add_node(canopen.RemoteNode(3, load_od("skin-patch", 3)))
        node.sdo.RESPONSE_TIMEOUT = 2.0
        got = [struct.unpack("<I", node.sdo.upload(0x2002, s))[0] for s in range(1, 28)]
        assert got == np.rint(rest.reshape(-1) * 1000).astype(int).tolist()
        other = network.add_node(canopen.RemoteNode(4, load_od("skin-patch", 4)))
        other.sdo.RESPONSE_TIMEOUT = 2.0
        assert struct.unpack("<I", other.sdo.upload(0x2002, 1))[0] == 1_000_000  # untouched
