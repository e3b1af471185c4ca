"""The host on udp_multicast, which hands a process its own frames back: the host claims what
it alone sends (its force nodes' PDOs, its SDO requests to its patches), so their echoes
never reach its data plane or canopen's listener, and it releases them on stop. The echo of
its SYNC it takes back: that is where the bus passed the SYNC, which closes a cycle. At its
force nodes' heartbeat and EMCY IDs it tells their echoes from another node's frames: it
finds exactly the other node, however its force nodes' first frames interleave."""

# mypy: disable-error-code="no-untyped-call"
from __future__ import annotations

import logging
import sys
from collections import Counter

import can
import canopen
import numpy as np
import pytest

from canbus.device.patch_server import PatchServer
from canbus.master.forcenode import ForceNode
from canbus.master.host import HostManager
from canbus.master.hostconfig import HostConfig, PatchConfig
from canbus.rxfilter import receive_filter
from tests.support.rigs.host import eventually, source

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="udp_multicast on loopback, a Linux socket filter")

REST = np.full((9, 3), 1000.0)


def _heard(force: ForceNode) -> set[int]:
    """The force node's heartbeat and EMCY: not claimed, for a second node there is heard."""
    return {0x700 + force.node_id, 0x080 + force.node_id}


def _config(sync_external: bool = False) -> HostConfig:
    return HostConfig(patches=[PatchConfig(node_id=5, mode="xyz")], sync_period_ms=10,
                      sync="external" if sync_external else "produce")


@pytest.mark.parametrize("where", ["kernel", "gate"])
def test_the_host_never_takes_back_its_own_frames(udp_channel: str, udp_port: int, where: str,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    if where == "gate":  # no socket filter: the gate in front of the listeners drops them
        monkeypatch.setattr("canbus.rxfilter._install", lambda *args: False)
    device_bus = can.Bus(interface="udp_multicast", channel=udp_channel, port=udp_port)
    host_bus = can.Bus(interface="udp_multicast", channel=udp_channel, port=udp_port)
    network = canopen.Network(device_bus)
    network.NOTIFIER_CYCLE = 0.05
    network.connect()
    server = PatchServer(network, source(5, REST))
    server.start()
    try:
        with HostManager(host_bus, _config()) as host:
            own = receive_filter(host_bus)
            force: ForceNode = host.patch(5).force_node
            assert {0x605} | force.cob_ids() - _heard(force) <= own.cob_ids
            assert 0x080 not in own.cob_ids and not _heard(force) & own.cob_ids
            assert own.in_kernel == (where == "kernel")
            eventually(lambda: host.stats()["samples"] >= 20, "20 samples")
            before = host.stats()  # the scan and the set-up's SDO traffic are behind
            eventually(lambda: host.stats()["samples"] >= before["samples"] + 100,
                       "100 more samples")
            after = host.stats()
        cycles = after["samples"] - before["samples"]
        unknown = after["unknown_frames"] - before["unknown_frames"]
        # Each cycle the host sends a SYNC and 8 force PDOs: the force PDOs taken back would be
        # 8 unknown frames a cycle. What is left is the patch's heartbeat (every 100 ms, 10
        # cycles), which is not the host's; the SYNC's echo is the bus's own traffic.
        assert unknown < cycles / 2, f"{unknown} unknown frames in {cycles} cycles"
        sync_echoes = after["bus_frames"] - before["bus_frames"]
        assert sync_echoes >= cycles - 2, f"{sync_echoes} SYNC echoes in {cycles} cycles"
        assert after["complete_samples"] > before["complete_samples"]  # and it decodes
        assert not own.cob_ids, "the host released its claims on stop"
    finally:
        server.stop()
        network.disconnect()
        host_bus.shutdown()


def test_a_host_following_sync_keeps_receiving_it(udp_channel: str, udp_port: int) -> None:
    with can.Bus(interface="udp_multicast", channel=udp_channel, port=udp_port) as host_bus, \
            HostManager(host_bus, _config(sync_external=True)) as host:
        assert 0x080 not in receive_filter(host_bus).cob_ids
        force: ForceNode = host.patch(5).force_node
        assert force.cob_ids() - _heard(force) <= receive_filter(host_bus).cob_ids


def test_a_remapped_force_node_is_claimed_anew(udp_channel: str, udp_port: int) -> None:
    with can.Bus(interface="udp_multicast", channel=udp_channel, port=udp_port) as host_bus, \
            HostManager(host_bus, _config()) as host:
        force: ForceNode = host.patch(5).force_node
        own = receive_filter(host_bus)
        first = min(c for c in force.cob_ids() if 0x180 <= c < 0x580)
        # Another master moves TPDO1 to 0x3F0 (invalid first, as CiA 301 asks).
        force.store.set_data(0x1800, 1, (first | 0x8000_0000).to_bytes(4, "little"), True)
        force.store.set_data(0x1800, 1, (0x3F0).to_bytes(4, "little"), True)
        assert 0x3F0 in own.cob_ids and first not in own.cob_ids


def _force_node_host(host_bus: can.BusABC, patches: int) -> HostManager:
    """A host of ``patches`` patches (none answers) whose force nodes beat every 200 ms."""
    config = HostConfig(patches=[PatchConfig(node_id=n, mode="xyz") for n in
                                 range(1, patches + 1)], force_heartbeat_ms=200)
    return HostManager(host_bus, config)


def _conflicts(host: HostManager) -> dict[int, str]:
    return {n: h.force_conflict for n, h in host.health().items() if h.force_conflict}


def test_the_first_frames_of_many_force_nodes_are_never_another_nodes(
        udp_channel: str, udp_port: int, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, logger="canbus.master.active")
    heard: Counter[int] = Counter()  # what the host received at its force nodes' IDs
    with can.Bus(interface="udp_multicast", channel=udp_channel, port=udp_port) as host_bus, \
            _force_node_host(host_bus, 12) as host:
        force_ids = [host.patch(n).force_node.node_id for n in range(1, 13)]
        for force_id in force_ids:  # after the host's own watcher: it judged what we count
            host.network.subscribe(0x700 + force_id, lambda cob_id, *_: heard.update([cob_id]))
        # The boot-ups and first heartbeats were sent as the host claimed its own frames.
        eventually(lambda: all(heard[0x700 + f] >= 3 for f in force_ids),
                   "3 heartbeats of each force node received by the host")
        assert not _conflicts(host)
    assert not [r for r in caplog.records if "another node" in r.getMessage()]


def test_a_second_node_sending_what_a_force_node_sends_is_found(
        udp_channel: str, udp_port: int, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, logger="canbus.master.active")
    with can.Bus(interface="udp_multicast", channel=udp_channel, port=udp_port) as host_bus, \
            can.Bus(interface="udp_multicast", channel=udp_channel, port=udp_port) as other, \
            _force_node_host(host_bus, 8) as host:
        # Node 72 (patch 8's force node) beats OPERATIONAL, as the force node does.
        other.send(can.Message(arbitration_id=0x748, data=b"\x05", is_extended_id=False))
        eventually(lambda: 8 in _conflicts(host), "the second node at 72 found")
        assert list(_conflicts(host)) == [8] and "0x748" in _conflicts(host)[8]
    lines = [r.getMessage() for r in caplog.records if "another node" in r.getMessage()]
    assert len(lines) == 1 and "ID of patch 8's force node" in lines[0]
