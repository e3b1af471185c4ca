"""A recorded calibration run in one process: a scene's simulated patches answering SYNC
with their true forces written as reference (``canbus.device.truth``), the host manager
configuring and running them, and a recorder keeping every frame, on a virtual bus."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path

import can
import canopen
import numpy as np

from canbus.device.patch_server import PatchServer
from canbus.device.truth import TruthSource, truth_log
from canbus.master.busconfig import BusConfig
from canbus.master.host import HostManager
from canbus.master.hostconfig import HostConfig, PatchConfig
from canbus.tools.recorder import Recorder
from sim import Simulator, load_scene, scene_from_dict
from tests.support.rigs.waiting import wait_until


def scene(mode: str = "xyz", faults: list[dict[str, object]] | None = None,
          nodes: tuple[int, ...] = (1,)) -> object:
    """The calibration scene in ``mode``, with pillar faults and these patches."""
    data = load_scene("calibration").to_dict()
    data["scene"]["mode"] = mode
    data["patches"] = [{"node_id": n, "position_m": [0.0, 0.0]} for n in nodes]
    data["loads"][0]["patches"] = list(nodes)
    if faults:
        data["effects"]["faults"] = {"pillars": faults}
    return scene_from_dict(data)


def record(folder: Path, channel: str, *, mode: str = "xyz", cycles: int = 60, seed: int = 1,
           fd: bool = False, faults: list[dict[str, object]] | None = None,
           nodes: tuple[int, ...] = (1,)) -> tuple[Path, Path]:
    """``folder/run.log`` and ``folder/truth.csv`` of ``cycles`` SYNCs after the patches run."""
    protocol = can.CanProtocol.CAN_FD if fd else can.CanProtocol.CAN_20

    def bus() -> can.BusABC:
        return can.Bus(interface="virtual", channel=channel, protocol=protocol)

    config = HostConfig(patches=tuple(PatchConfig(n, mode=mode) for n in nodes),
                        sync_period_ms=10.0, heartbeat_ms=100, scan_ms=100,
                        buses=(BusConfig(fd=fd),))
    listen = bus()
    recorder = Recorder(folder / "run.log")
    notifier = can.Notifier(listen, [recorder], timeout=0.05)
    device = canopen.Network(bus())
    device.NOTIFIER_CYCLE = 0.05
    device.connect()
    host_bus = bus()
    truth = TruthSource(Simulator(scene(mode, faults, nodes), seed=seed))  # type: ignore[arg-type]
    try:
        with PatchServer(device, truth, event_rate_hz=0.0) as server, \
                truth_log(folder / "truth.csv", device, truth, server.nodes):
            host = HostManager(host_bus, config)
            host.start()
            try:
                assert host.wait_operational(timeout=15.0), host.health()
                start = host.sync.cycle
                wait_until(lambda: host.sync.cycle >= start + cycles,
                           what=f"{cycles} SYNC cycles", timeout=120.0)
            finally:
                host.stop()
    finally:
        device.disconnect()
        notifier.stop(timeout=1.0)
        listen.shutdown()
        host_bus.shutdown()
    return folder / "run.log", folder / "truth.csv"


def rewrite(source: Path, target: Path, keep: Callable[[int, can.Message], bool],
            more: Iterable[can.Message] = ()) -> None:
    """A copy of a .log recording with only the frames ``keep(index, msg)`` accepts, then
    ``more``."""
    with can.LogReader(source) as reader, can.Logger(target) as writer:
        for k, msg in enumerate(reader):
            if keep(k, msg):
                writer.on_message_received(msg)
        for msg in more:
            writer.on_message_received(msg)


def steps(scene_: object, seed: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The simulator's first ``n`` steps: (resistance (n, patches, 9, P), force)."""
    frame = Simulator(scene_, seed=seed).run(n)  # type: ignore[arg-type]
    return frame.resistance_ohm, frame.force_N


def assert_rows_are_steps(resistance: np.ndarray, force: np.ndarray, scene_: object,
                          seed: int) -> int:
    """Every loaded row (patch 0) is one step of the simulator, its readings bit for bit;
    returns the rows checked (rest rows, all alike, are skipped)."""
    r, f = steps(scene_, seed, 3000)
    flat = f[:, 0].reshape(len(f), -1)
    checked = 0
    for i in range(resistance.shape[0]):
        if not force[i, 0].any():
            continue
        k = np.flatnonzero(np.all(flat == force[i, 0].reshape(-1), axis=1))
        assert k.size == 1, f"row {i}: its force is no single step of the simulator"
        np.testing.assert_array_equal(resistance[i, 0], r[k[0], 0], err_msg=f"row {i}")
        checked += 1
    return checked
