"""A host on a virtual bus with simulated patches, each on its own canopen Network (as
separate devices would be), and a spy bus that records every frame; and the values tests
feed it (a press quantised as a patch sends it, what the analytic decoder makes of it)."""

from __future__ import annotations

from collections.abc import Callable

import can
import canopen
import numpy as np

from canbus import codes
from canbus.device.patch_server import PatchServer
from canbus.device.source import ArraySource
from canbus.master.cobids import predefined_tpdo_cob_ids
from canbus.master.dataplane import ForceFrame
from canbus.master.discovery import UnknownNode
from canbus.master.host import HostManager
from canbus.master.hostconfig import HostConfig, PatchConfig
from decoder.analytic import AnalyticDecoder
from skin.constants import DEFAULT_CONSTANTS
from skin.tripod import resistance_from_force
from tests.support.rigs.waiting import wait_until

LSB = DEFAULT_CONSTANTS.resistance_lsb_ohm
R0 = DEFAULT_CONSTANTS.nominal_resistance_ohm
WAIT_S = 30.0  # generous: conditions are awaited, never slept for


def press(loads: dict[int, tuple[float, float, float]], pillars: int = 3) -> np.ndarray:
    """(9, P) resistances of the given taxel forces, quantised as the patch sends them."""
    force = np.zeros((9, 3))
    for taxel, f in loads.items():
        force[taxel] = f
    r = resistance_from_force(force, DEFAULT_CONSTANTS)[:, :pillars]
    return np.asarray(codes.resistance_to_code(r, LSB), dtype=np.float64) * LSB


def expected(resistance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What the analytic decoder makes of one patch's resistances: force (9, 3), reason."""
    out = AnalyticDecoder().decode(resistance[None])
    return out.force_N[0], out.reason[0]


def source(node_id: int, *samples: np.ndarray) -> ArraySource:
    return ArraySource(np.stack(samples)[:, None], (node_id,))


def eventually(condition: Callable[[], object], what: str, timeout: float = WAIT_S) -> None:
    wait_until(condition, what=what, timeout=timeout)


class Rig:
    """Patches, a spy and a host on one virtual channel."""

    def __init__(self, channel: str) -> None:
        self.channel = channel
        self.servers: dict[int, tuple[canopen.Network, PatchServer]] = {}
        self.spy_bus = can.Bus(interface="virtual", channel=channel)
        self.seen: list[can.Message] = []
        self.spy = can.Notifier(self.spy_bus, [self.seen.append], timeout=0.05)
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.unknown: list[UnknownNode] = []
        self.frames: list[ForceFrame] = []
        self.host: HostManager | None = None

    def network(self) -> canopen.Network:
        net = canopen.Network()
        net.NOTIFIER_CYCLE = 0.05
        return net.connect(interface="virtual", channel=self.channel)

    def serve(self, node_id: int, src: ArraySource) -> PatchServer:
        net = self.network()
        server = PatchServer(net, src)
        server.start()
        self.servers[node_id] = (net, server)
        return server

    def kill(self, node_id: int) -> None:
        net, server = self.servers.pop(node_id)
        server.stop()
        net.disconnect()

    def start(self, config: HostConfig) -> HostManager:
        self.host = HostManager(self.bus, config, on_unknown=self.unknown.append)
        self.host.on_forces(self.frames.append)
        self.host.start()
        return self.host

    def frames_of(self, patch: int, after: int = 0) -> list[ForceFrame]:
        return [f for f in list(self.frames) if f.patch == patch and f.cycle > after]

    def close(self) -> None:
        if self.host is not None:
            self.host.stop()
        for node_id in list(self.servers):
            self.kill(node_id)
        self.spy.stop(timeout=1.0)
        self.spy_bus.shutdown()
        self.bus.shutdown()


def config(*patches: PatchConfig, **host: object) -> HostConfig:
    # heartbeat 200 ms: lost after 300 ms of silence, not by a busy machine's jitter
    defaults: dict[str, object] = {"sync_period_ms": 10.0, "scan_ms": 100, "heartbeat_ms": 200}
    return HostConfig(patches=patches, **{**defaults, **host})  # type: ignore[arg-type]


def force_pdos(seen: list[can.Message], force_node: int) -> dict[int, bytes]:
    """The last payload of each of the force node's default TPDOs."""
    ids = set(predefined_tpdo_cob_ids(force_node))
    return {m.arbitration_id: bytes(m.data) for m in list(seen) if m.arbitration_id in ids}


def decode_force_pdos(payloads: dict[int, bytes], force_node: int) -> tuple[np.ndarray, int]:
    """27 INTEGER16 mN (TPDO 1..7, 4 per PDO) and the 0x2005 valid bits."""
    data = b"".join(payloads[c] for c in predefined_tpdo_cob_ids(force_node))
    values = np.frombuffer(data, dtype="<i2")
    return values[:27].reshape(9, 3), int(np.frombuffer(data[54:56], dtype="<u2")[0])


class Rest:
    """Every patch at rest."""

    pillars = 3

    def __init__(self, n: int) -> None:
        self.node_ids = tuple(range(1, n + 1))
        self._sample = np.tile(DEFAULT_CONSTANTS.nominal_resistance_ohm, (n, 9, 1))

    def read(self) -> np.ndarray:
        return self._sample
