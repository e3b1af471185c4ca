"""The listen-only host: it decodes what another master runs and sends nothing.

- Live: patches run by a normal ``HostManager`` (the "other master"), and a listen-only
  host with the same config on the same virtual channel. Every bus object counts what it
  sends; a listener counts every frame on the channel: all of them come from the patches
  and the master, none from the listen-only host. Its force frames are the master's, bit
  for bit, cycle by cycle (SYNC counter, completeness, the EMCY-masked taxel), never
  published.
- Scripted: frames written by hand (boot-up, NMT commands from any master, heartbeats,
  SYNC with and without counter, PDOs packed here, EMCY) drive every state the host
  follows: absent, pre-operational (``configuring``), operational, stopped, lost and
  back, a started patch that never answers is lost, an unknown node is reported without
  SDO; its bus object sends nothing throughout.
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable, Iterator
from typing import Any

import can
import can.interfaces.virtual
import canopen
import numpy as np
import pytest

from canbus import codes
from canbus.device.patch_server import PatchServer
from canbus.device.source import ArraySource
from canbus.master.dataplane import ForceFrame
from canbus.master.discovery import UnknownNode
from canbus.master.host import HostManager
from canbus.master.hostconfig import HostConfig, PatchConfig
from decoder.analytic import AnalyticDecoder
from decoder.reasons import Reason
from skin.constants import DEFAULT_CONSTANTS
from skin.tripod import resistance_from_force
from tests.support.rigs.host import press
from tests.support.rigs.waiting import wait_until

LSB = DEFAULT_CONSTANTS.resistance_lsb_ohm
WAIT_S = 30.0


class CountingBus(can.interfaces.virtual.VirtualBus):
    """A virtual bus that counts every frame sent through it (periodic ones included:
    python-can's periodic tasks send through ``send``)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.sent = 0
        self._count = threading.Lock()

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        with self._count:
            self.sent += 1
        super().send(msg, timeout)


def eventually(condition: Callable[[], object], what: str, timeout: float = WAIT_S) -> None:
    wait_until(condition, what=what, timeout=timeout, interval=0.002)


def _key(frame: ForceFrame) -> tuple[int, int]:
    return (frame.cycle, frame.patch)


# -- live: another master runs the patches --------------------------------------------------


def test_a_listen_only_host_sends_nothing_and_decodes_what_another_master_runs(
        request: pytest.FixtureRequest) -> None:
    channel = f"listen-{request.node.name}"
    count = 24
    force = np.zeros((count, 2, 9, 3))
    for k in range(count):
        force[k, 0, k % 9] = (0.1, 0.2, 0.2 * (k % 4))
        force[k, 1, (k + 4) % 9] = (0.0, -0.2, 1.0)
    r = resistance_from_force(force, DEFAULT_CONSTANTS)
    r[5, 1, 2, 0] = np.inf  # pillar z of patch 2's taxel 2 open for one sample: EMCY, reset
    config = HostConfig(patches=(PatchConfig(1), PatchConfig(2)), sync_period_ms=20.0,
                        heartbeat_ms=200, scan_ms=100)
    listener = can.Bus(interface="virtual", channel=channel)
    device_bus = CountingBus(channel=channel)
    devices = canopen.Network(device_bus)
    devices.NOTIFIER_CYCLE = 0.05
    devices.connect()
    master_bus, quiet_bus = CountingBus(channel=channel), CountingBus(channel=channel)
    server = PatchServer(devices, ArraySource(r, (1, 2)))
    master_frames: list[ForceFrame] = []
    quiet_frames: list[ForceFrame] = []
    try:
        server.start()  # the patches boot before either host listens
        quiet = HostManager(quiet_bus, config, listen_only=True)
        quiet.on_forces(quiet_frames.append)
        master = HostManager(master_bus, config)
        master.on_forces(master_frames.append)
        with quiet:
            with master:
                assert master.wait_operational(timeout=WAIT_S), master.health()
                assert quiet.wait_operational(timeout=WAIT_S), quiet.health()
                eventually(lambda: sum(f.patch == 2 for f in master_frames) >= 14, "frames")
            assert quiet.health()[1].state == "operational"  # still heard, no more SYNC
        server.stop()
    finally:
        devices.disconnect()
        master_bus.shutdown()
        quiet_bus.shutdown()
    heard = 0
    while listener.recv(timeout=0) is not None:
        heard += 1
    listener.shutdown()
    assert quiet_bus.sent == 0 and master_bus.sent > 0 and device_bus.sent > 0
    # every frame on the channel came from the patches' bus or the master's
    assert heard == master_bus.sent + device_bus.sent
    # and the listen-only host decoded the master's forces, cycle by cycle
    assert sorted(map(_key, quiet_frames)) == sorted(map(_key, master_frames))
    for a, b in zip(sorted(quiet_frames, key=_key), sorted(master_frames, key=_key),
                    strict=True):
        assert (a.sync_counter, a.complete, a.force_node) == \
            (b.sync_counter, b.complete, b.force_node), _key(b)
        np.testing.assert_array_equal(a.force_N, b.force_N)
        np.testing.assert_array_equal(a.reason, b.reason)
        assert not a.published and (b.published or not b.complete)
    assert any(f.reason[2] == Reason.FAULTY for f in quiet_frames if f.patch == 2)
    assert quiet.stats()["frames_out"] == 0 and not quiet.unknown_nodes


# -- scripted: every state the host follows -------------------------------------------------

XYZ_COB_IDS = (0x181, 0x281, 0x381, 0x481, 0x201, 0x301, 0x401)
Z_COB_IDS = (0x182, 0x282, 0x382)


def xyz_pdos(resistance: np.ndarray) -> list[tuple[int, bytes]]:
    """Patch 1 mapped for 3 axes: 27 UNSIGNED16 codes (taxel-major z, x, y), 4 per TPDO,
    sent in COB-ID order as a patch answers."""
    data = codes.resistance_to_code(resistance, LSB).astype("<u2").tobytes()
    return sorted((cob, data[8 * n:8 * n + 8]) for n, cob in enumerate(XYZ_COB_IDS))


def z_pdos(resistance: np.ndarray) -> list[tuple[int, bytes]]:
    """Patch 2 mapped for z: pillar z of one grid row (3 taxels) per TPDO."""
    data = codes.resistance_to_code(resistance[:, 0], LSB).astype("<u2").tobytes()
    return [(cob, data[6 * n:6 * n + 6]) for n, cob in enumerate(Z_COB_IDS)]


class Script:
    """A bus on which the test plays the patches and their master, frame by frame, and
    a listen-only host on a counting bus."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.quiet = CountingBus(channel=channel)
        self.frames: list[ForceFrame] = []
        self.unknown: list[UnknownNode] = []
        config = HostConfig(patches=(PatchConfig(1), PatchConfig(2, mode="z")),
                            sync_period_ms=10.0, heartbeat_ms=200)
        self.host = HostManager(self.quiet, config, listen_only=True,
                                on_unknown=self.unknown.append)
        self.host.on_forces(self.frames.append)
        self.counters = itertools.count(7)
        # patch 1's heartbeat, every 50 ms (lost after 300 ms of silence)
        self.beat: can.broadcastmanager.ModifiableCyclicTaskABC | None = None

    def send(self, cob_id: int, data: bytes | list[int] = b"") -> None:
        self.bus.send(can.Message(arbitration_id=cob_id, data=bytes(data), is_extended_id=False))

    def heartbeat(self, state: int) -> None:
        msg = can.Message(arbitration_id=0x701, data=[state], is_extended_id=False)
        if self.beat is None:
            task = self.bus.send_periodic(msg, 0.05)
            assert isinstance(task, can.broadcastmanager.ModifiableCyclicTaskABC)
            self.beat = task
        else:
            self.beat.modify_data(msg)

    def state(self, node_id: int) -> str:
        return self.host.health()[node_id].state

    def wait_state(self, node_id: int, state: str) -> None:
        eventually(lambda: self.state(node_id) == state, f"patch {node_id} {state}")

    def cycle(self, *pdos: list[tuple[int, bytes]], counter: bool = True) -> int:
        """One SYNC and the PDOs answering it; the SYNC counter byte sent (0: none)."""
        value = next(self.counters) if counter else 0
        self.send(0x080, [value] if counter else b"")
        for frames in pdos:
            for cob_id, data in frames:
                self.send(cob_id, data)
        return value

    def close(self) -> None:
        if self.beat is not None:
            self.beat.stop()
        self.host.stop()
        self.bus.shutdown()
        self.quiet.shutdown()


@pytest.fixture
def script(request: pytest.FixtureRequest) -> Iterator[Script]:
    s = Script(f"listen-{request.node.name}")
    yield s
    s.close()


def test_the_listen_only_host_follows_nmt_heartbeats_and_emcy(script: Script) -> None:
    host = script.host
    xyz = press({4: (0.3, -0.2, 2.0), 0: (0.0, 0.0, 0.5)})
    z = press({2: (0.0, 0.0, 1.5), 7: (0.0, 0.0, 3.0)}, pillars=1)
    want_xyz = AnalyticDecoder().decode(xyz[None])
    want_z = AnalyticDecoder().decode(z[None])
    host.start()
    assert {n: h.state for n, h in host.health().items()} == {1: "absent", 2: "absent"}

    def frame(patch: int, counter: int) -> ForceFrame:
        eventually(lambda: any(f.sync_counter == counter and f.patch == patch
                               for f in script.frames), f"patch {patch}'s frame {counter}")
        return next(f for f in script.frames if f.sync_counter == counter and f.patch == patch)

    # patch 1 boots (pre-operational), its master starts it: decoded from then on
    script.send(0x701, [0x00])
    script.heartbeat(0x7F)
    script.wait_state(1, "configuring")
    script.cycle(xyz_pdos(xyz))  # not started yet: nothing decoded
    script.send(0x000, [0x01, 0x01])
    script.wait_state(1, "operational")
    script.heartbeat(0x05)
    first = frame(1, script.cycle(xyz_pdos(xyz)))
    assert first.complete and first.valid.all() and not first.published
    assert first.force_node == 65 and first.cycle == 2  # every SYNC received opens a cycle
    np.testing.assert_allclose(first.force_N, want_xyz.force_N[0], rtol=0, atol=1e-12)
    # patch 2 was never heard: one sample per SYNC all the same, with no valid taxel
    assert all(not f.valid.any() for f in script.frames if f.patch == 2)
    # EMCY: taxel 4 masked from its place on the bus, neighbours decode; then reset
    script.send(0x081, [0x00, 0x50, 0x81, 0x04, 0x02, 0, 0, 0])
    masked = frame(1, script.cycle(xyz_pdos(xyz)))
    assert masked.reason[4] == Reason.FAULTY and not masked.valid[4]
    assert masked.valid[np.arange(9) != 4].all() and host.health()[1].faulty_taxels == (4,)
    script.send(0x081, [0x00, 0x00, 0x00, 0x04, 0x00, 0, 0, 0])
    assert frame(1, script.cycle(xyz_pdos(xyz))).valid.all()
    # a SYNC without counter; a PDO missing: incomplete at the next SYNC, MISSING taxels
    assert script.cycle(xyz_pdos(xyz)[:-1], counter=False) == 0  # the last: TPDO 4
    script.cycle()
    short = frame(1, 0)
    assert not short.complete and list(np.flatnonzero(short.reason == Reason.MISSING)) == [4, 5]
    # another master stops it, then starts every node: patch 2 (never heard) too
    script.send(0x000, [0x02, 0x01])
    script.heartbeat(0x04)
    script.wait_state(1, "stopped")
    script.send(0x000, [0x01, 0x00])
    script.heartbeat(0x05)
    script.wait_state(1, "operational")
    script.wait_state(2, "operational")
    both = script.cycle(xyz_pdos(xyz), z_pdos(z))
    f2 = frame(2, both)
    assert f2.complete and f2.force_node == 66 and frame(1, both).complete
    np.testing.assert_allclose(f2.force_N, want_z.force_N[0], rtol=0, atol=1e-12)
    # patch 2's heartbeat never comes: lost within two periods; back with its heartbeat
    script.wait_state(2, "lost")
    assert host.health()[1].state == "operational"  # patch 1 beats on
    script.send(0x702, [0x05])
    script.wait_state(2, "operational")
    # patch 1's heartbeat says pre-operational (an NMT command this host did not see)
    script.heartbeat(0x7F)
    script.wait_state(1, "configuring")
    script.heartbeat(0x05)
    script.wait_state(1, "operational")
    # a node that is not configured boots: reported, not asked anything
    script.send(0x705, [0x00])
    eventually(lambda: script.unknown, "the unknown node")
    assert script.unknown[0].node_id == 5 and script.unknown[0].identity is None
    host.stop()
    assert script.quiet.sent == 0
    stats = host.stats()
    assert stats["frames_out"] == 0 and stats["sync_cycles"] == 7 and stats["late_frames"] == 0
