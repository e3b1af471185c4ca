"""A host publishing on Zenoh over loopback, for the Zenoh tests: patches served on a
private virtual bus, presses of known forces, the publisher on a TCP port of 127.0.0.1 of
its own (``tests.support.rigs.ports``), multicast scouting off."""

from __future__ import annotations

import contextlib
import itertools
import os
import threading
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field

import can
import canopen
import numpy as np

from canbus.device.patch_server import PatchServer
from canbus.device.source import ArraySource
from canbus.master.dataplane import ForceFrame
from canbus.master.host import HostManager
from canbus.master.hostconfig import HostConfig, PatchConfig
from canbus.master.zenoh_settings import ZenohSettings
from canbus.zenoh.publisher import ZenohPublisher
from skin.constants import DEFAULT_CONSTANTS
from skin.placement import PatchPlacement
from skin.tripod import resistance_from_force
from tests.support.rigs.ports import tcp_port

_channels = itertools.count()


def presses(samples: int, patches: int, seed: int = 5) -> np.ndarray:
    """(samples, patches, 9, 3) resistances of random 3-axis presses."""
    rng = np.random.default_rng(seed)
    force = np.zeros((samples, patches, 9, 3))
    force[..., 2] = rng.uniform(0.0, 4.0, (samples, patches, 9))
    force[..., :2] = rng.uniform(-0.3, 0.3, (samples, patches, 9, 2))
    return resistance_from_force(force, DEFAULT_CONSTANTS)


@dataclass
class Rig:
    host: HostManager
    publisher: ZenohPublisher
    endpoint: str
    bus: can.BusABC  # the host's bus
    patch_bus: can.BusABC  # the patches' bus: frames sent here reach the host
    channel: str  # the virtual channel: another bus on it sees both sides
    server: PatchServer  # the simulated patches (stopped: they fall silent, the host loses them)
    frames: list[ForceFrame] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    @property
    def reader_settings(self) -> ZenohSettings:
        return ZenohSettings(connect=(self.endpoint,), prefix=self.publisher.settings.prefix)

    def by_cycle(self) -> dict[tuple[int, int], ForceFrame]:
        with self.lock:
            return {(f.patch, f.cycle): f for f in self.frames}


@contextlib.contextmanager
def publishing_host(patches: tuple[int, ...] = (1, 2), *, period_ms: float = 20.0,
                    settings: ZenohSettings | None = None,
                    host_name: str = "test-host",
                    placements: Mapping[int, PatchPlacement] | None = None) -> Iterator[Rig]:
    """A running host publishing on Zenoh (see the module docstring); ``placements``: the
    patches' places on the robot's links, by node-ID."""
    channel = f"zenoh-test-{os.getpid()}-{next(_channels)}"
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.05
    network.connect(interface="virtual", channel=channel)
    bus = can.Bus(interface="virtual", channel=channel)
    placed = placements or {}
    config = HostConfig(patches=tuple(PatchConfig(n, placement=placed.get(n)) for n in patches),
                        sync_period_ms=period_ms, scan_ms=300, sdo_timeout_ms=2000,
                        heartbeat_ms=500)
    endpoint = f"tcp/127.0.0.1:{tcp_port()}"
    settings = settings or ZenohSettings(listen=(endpoint,), host=host_name)
    if settings.listen:
        endpoint = settings.listen[0]
    server = PatchServer(network, ArraySource(presses(50, len(patches)), patches))
    assert network.bus is not None
    try:
        with server, HostManager(bus, config) as host:
            rig = Rig(host, ZenohPublisher(host, settings), endpoint, bus, network.bus, channel,
                      server)

            def keep(frame: ForceFrame) -> None:
                with rig.lock:
                    rig.frames.append(frame)

            host.on_forces(keep)
            assert host.wait_operational(timeout=15.0), host.health()
            with rig.publisher:
                yield rig
    finally:
        bus.shutdown()
        network.disconnect()
