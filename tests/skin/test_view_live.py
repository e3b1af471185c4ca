"""The live view on a bus of 8 patches at 100 Hz: it shows every sample the host publishes.

As ``skin demo`` builds them: 8 simulated patches of the indenter scene (a precomputed
simulation served one step per SYNC) and the host manager on one virtual channel, every
thread free to run on any CPU. The view twice: as ``skin view`` reads a bus (a
``ForceReader`` taking the force PDOs, drawn by ``draw_live``) and as ``skin demo`` shows
it (``SkinView.update`` as the host's callback, drawn by a ``LiveThread``), both at the
default redraw rate into a terminal-sized console. The reader listens on the simulated
patches' bus, which receives every force PDO anyway, as the demo's latency clock does.

Both views count exactly the samples the host published, complete and incomplete, and
neither sees a partial one, however busy the machine. What drawing costs the host (late
frames with and without the view) is a figure of ``python -m tests.support.view``, not a test.
"""

from __future__ import annotations

import io
from dataclasses import dataclass

import can
import canopen
import numpy as np
from rich.console import Console

from canbus.device.patch_server import PatchServer
from canbus.device.source import ArraySource
from canbus.master.host import HostManager, PatchHealth
from canbus.master.hostconfig import HostConfig, PatchConfig
from canbus.tools.forcereader import ForceReader
from sim import Scene, Simulator
from skin.commands.demo import demo_scene
from skin.commands.view.layout import layout_from_positions
from skin.commands.view.live import LiveStats, LiveThread, draw_live
from skin.commands.view.term import SkinView
from tests.support.rigs.waiting import wait_until

PATCHES = 8
SAMPLES = 100  # per patch: a second at 100 Hz


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


def _run(scene: Scene, resistance: np.ndarray, samples: int) -> Run:
    config = HostConfig(patches=tuple(PatchConfig(n, mode=scene.mode) for n in scene.node_ids),
                        sync_period_ms=1000.0 / scene.rate_hz, scan_ms=100).check()
    layout = layout_from_positions({p.node_id: p.position_m for p in scene.patches}, "scene")
    channel = "view-8-patches"
    patch_net = canopen.Network()
    patch_net.NOTIFIER_CYCLE = 0.05
    patch_net.connect(interface="virtual", channel=channel)
    host_bus = can.Bus(interface="virtual", channel=channel)
    server = PatchServer(patch_net, ArraySource(resistance, scene.node_ids))
    host = HostManager(host_bus, config)
    run = Run({}, {}, 0, ForceReader(), SkinView(layout), SkinView(layout))
    host.on_forces(run.callback_view.update)
    run.reader.on_sample(run.bus_view.update)
    run.reader.start()
    assert patch_net.notifier is not None
    patch_net.notifier.add_listener(run.reader)  # before the first SYNC: every sample

    def enough() -> bool:
        drawn = run.thread is not None and run.thread.stats.redraws >= 2
        return drawn and min(h.samples for h in host.health().values()) >= samples

    try:
        with server, host:
            assert host.wait_operational(timeout=30.0), host.health()
            with LiveThread(run.callback_view, console=_console()) as thread:
                run.thread = thread
                run.drawn = draw_live(run.bus_view, enough, console=_console())
        run.figures, run.health = host.stats(), host.health()
        run.frames_sent = server.frames_sent
        wait_until(lambda: run.reader.frames == run.figures["frames_out"],
                   what="the reader took every force frame")
    finally:
        host_bus.shutdown()
        patch_net.disconnect()
        run.reader.stop()
    return run


def test_the_live_view_of_8_patches_shows_every_sample_the_host_published() -> None:
    scene = demo_scene("indenter", PATCHES)
    resistance = Simulator(scene).run(SAMPLES + 200).resistance_ohm
    run = _run(scene, resistance, SAMPLES)
    figures = run.figures
    assert run.reader.frames == figures["frames_out"] == 8 * figures["samples"]  # 7 + contact
    assert run.drawn is not None and run.thread is not None and run.thread.error is None
    assert run.drawn.redraws >= 1 and run.thread.stats.redraws >= 2
    read = run.bus_view.state().statuses
    called = run.callback_view.state().statuses
    for node in scene.node_ids:
        health = run.health[node]
        assert health.samples >= SAMPLES
        assert (read[node].samples, read[node].incomplete, read[node].partial) == \
            (health.samples, health.incomplete, 0)
        assert (called[node].samples, called[node].incomplete) == \
            (health.samples, health.incomplete)
