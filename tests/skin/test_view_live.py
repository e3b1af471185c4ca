"""The live view on a bus of 8 patches at 100 Hz: it drops redraws, never frames.

As ``skin demo`` builds them: 8 simulated patches of the indenter scene (a precomputed
simulation served one step per SYNC) and the host manager on one virtual channel, every
thread free to run on any CPU. The view twice: as ``skin view`` reads a bus (a
``ForceReader`` taking the force PDOs, drawn by ``draw_live``) and as ``skin demo`` shows
it (``SkinView.update`` as the host's callback, drawn by a ``LiveThread``), both at the
default redraw rate into a terminal-sized console. The reader listens on the simulated
patches' bus, which receives every force PDO anyway, as the demo's latency clock does: in
one process a bus of its own would copy every frame once more and add a receiving
thread, a cost ``skin view`` pays in a process of its own, not the host's. The host's
counters say whether the data path was held up.

Whether the view costs frames can only be judged when the host alone loses none: on a
machine so busy that it does (other work on both cores), the test first runs the host
without the view and skips, saying so, if that run already lost frames.
"""

from __future__ import annotations

import gc
import io
import time
from dataclasses import dataclass

import can
import canopen
import numpy as np
import pytest
from rich.console import Console

from canbus.device.patch_server import PatchServer
from canbus.device.source import ArraySource
from canbus.master.host import HostManager, PatchHealth
from canbus.master.hostconfig import HostConfig, PatchConfig
from canbus.tools.forcereader import ForceReader
from sim import Scene, Simulator
from skin.commands.demo import demo_scene
from skin.commands.view.layout import layout_from_positions
from skin.commands.view.live import DEFAULT_REFRESH_HZ, LiveStats, LiveThread, draw_live
from skin.commands.view.term import SkinView

PATCHES = 8
SECONDS = 2.0
LOSSES = ("late_frames", "duplicate_frames", "out_of_order_frames", "malformed_frames",
          "incomplete_samples", "send_errors", "callback_errors", "api_dropped")


def _console() -> Console:
    return Console(file=io.StringIO(), force_terminal=True, color_system="truecolor",
                   width=200, height=60)


@dataclass
class Run:
    figures: dict[str, int]
    health: dict[int, PatchHealth]
    frames_sent: int
    reader: ForceReader
    bus_view: SkinView
    callback_view: SkinView
    drawn: LiveStats | None = None
    thread: LiveThread | None = None

    def losses(self) -> dict[str, int]:
        return {k: self.figures[k] for k in LOSSES}


def _run(scene: Scene, resistance: np.ndarray, seconds: float, view: bool, k: int) -> Run:
    config = HostConfig(patches=tuple(PatchConfig(n, mode=scene.mode) for n in scene.node_ids),
                        sync_period_ms=1000.0 / scene.rate_hz, scan_ms=100).check()
    layout = layout_from_positions({p.node_id: p.position_m for p in scene.patches}, "scene")
    channel = f"view-8-patches-{k}"
    patch_net = canopen.Network()
    patch_net.NOTIFIER_CYCLE = 0.05
    patch_net.connect(interface="virtual", channel=channel)
    host_bus = can.Bus(interface="virtual", channel=channel)
    server = PatchServer(patch_net, ArraySource(resistance, scene.node_ids))
    host = HostManager(host_bus, config)
    run = Run({}, {}, 0, ForceReader(), SkinView(layout), SkinView(layout))
    if view:
        host.on_forces(run.callback_view.update)
        run.reader.on_sample(run.bus_view.update)
        run.reader.start()
        assert patch_net.notifier is not None
        patch_net.notifier.add_listener(run.reader)  # before the first SYNC: every sample
    gc.collect()
    gc.freeze()  # as skin demo does: no full collection of the dictionaries mid-run
    try:
        with server, host:
            assert host.wait_operational(timeout=10.0), host.health()
            started = time.monotonic()
            if view:
                with LiveThread(run.callback_view, console=_console()) as thread:
                    run.drawn = draw_live(run.bus_view,
                                          lambda: time.monotonic() - started > seconds,
                                          console=_console())
                run.thread = thread
            else:
                time.sleep(seconds)
        run.figures, run.health = host.stats(), host.health()
        run.frames_sent = server.frames_sent
    finally:
        gc.unfreeze()
        host_bus.shutdown()
        patch_net.disconnect()
        run.reader.stop()
    return run


def test_the_live_view_of_8_patches_at_100_hz_costs_the_host_no_frame() -> None:
    scene = demo_scene("indenter", PATCHES)
    resistance = Simulator(scene).run(int(SECONDS * scene.rate_hz) + 200).resistance_ohm
    alone = _run(scene, resistance, 1.5, view=False, k=0)
    if any(alone.losses().values()):
        pytest.skip(f"the host alone lost frames on this machine now ({alone.losses()}): "
                    "too busy to judge what the view costs")
    run = _run(scene, resistance, SECONDS, view=True, k=1)
    figures = run.figures
    assert run.losses() == dict.fromkeys(LOSSES, 0), figures
    assert figures["frames_in"] == run.frames_sent  # every patch frame was used in time
    assert run.reader.frames == figures["frames_out"] == 7 * figures["samples"]
    least = 0.5 * DEFAULT_REFRESH_HZ * SECONDS
    assert run.drawn is not None and run.thread is not None and run.thread.error is None
    assert run.drawn.redraws >= least and run.thread.stats.redraws >= least
    read = run.bus_view.state().statuses
    called = run.callback_view.state().statuses
    for node in scene.node_ids:
        samples = run.health[node].samples
        assert samples >= 0.8 * scene.rate_hz * SECONDS
        assert (read[node].samples, read[node].incomplete, read[node].partial) == (samples, 0, 0)
        assert (called[node].samples, called[node].incomplete) == (samples, 0)
