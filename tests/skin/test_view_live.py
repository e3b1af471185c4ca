"""The live view on a bus of 8 patches at 100 Hz: it drops redraws, never frames.

As ``skin demo`` builds them: 8 simulated patches of the indenter scene (a precomputed
simulation served one step per SYNC) and the host manager on one virtual channel, every
thread free to run on any CPU. On the same channel, the view as ``skin view`` runs it (a
``ForceReader`` on a bus of its own, drawn by ``draw_live``) and as the demo will
(``SkinView.update`` as the host's callback, drawn by a ``LiveThread``), both at the
default redraw rate into a terminal-sized console. The host's counters say whether the
data path was held up.
"""

from __future__ import annotations

import gc
import io
import time

import can
import canopen
from rich.console import Console

from canbus.device.patch_server import PatchServer
from canbus.device.source import ArraySource
from canbus.master.host import HostManager
from canbus.master.hostconfig import HostConfig, PatchConfig
from sim import Simulator
from skin.commands.demo import _scene
from skin.commands.view_layout import layout_from_positions
from skin.commands.view_live import DEFAULT_REFRESH_HZ, LiveThread, draw_live
from skin.commands.view_sources import BusForces
from skin.commands.view_term import SkinView

PATCHES = 8
SECONDS = 2.0


def _console() -> Console:
    return Console(file=io.StringIO(), force_terminal=True, color_system="truecolor",
                   width=200, height=60)


def test_the_live_view_of_8_patches_at_100_hz_costs_the_host_no_frame() -> None:
    scene = _scene("indenter", PATCHES)
    steps = int(SECONDS * scene.rate_hz) + 200
    simulated = Simulator(scene).run(steps)
    config = HostConfig(patches=tuple(PatchConfig(n, mode=scene.mode) for n in scene.node_ids),
                        sync_period_ms=1000.0 / scene.rate_hz, scan_ms=100).check()
    layout = layout_from_positions({p.node_id: p.position_m for p in scene.patches}, "scene")
    channel = "view-8-patches"
    patch_net = canopen.Network()
    patch_net.NOTIFIER_CYCLE = 0.05
    patch_net.connect(interface="virtual", channel=channel)
    host_bus = can.Bus(interface="virtual", channel=channel)
    view_bus = can.Bus(interface="virtual", channel=channel)
    server = PatchServer(patch_net, ArraySource(simulated.resistance_ohm, scene.node_ids))
    host = HostManager(host_bus, config)
    bus_view, callback_view = SkinView(layout), SkinView(layout)
    host.on_forces(callback_view.update)
    source = BusForces(view_bus, None)
    source.start(bus_view)  # before the first SYNC: every sample is read
    gc.collect()
    gc.freeze()  # as skin demo does: no full collection of the dictionaries mid-run
    try:
        with server, host:
            assert host.wait_operational(timeout=10.0), host.health()
            started = time.monotonic()
            with LiveThread(callback_view, console=_console()) as drawn:
                stats = draw_live(bus_view, lambda: time.monotonic() - started > SECONDS,
                                  console=_console())
        figures = host.stats()
        health = host.health()
    finally:
        gc.unfreeze()
        source.stop()
        view_bus.shutdown()
        host_bus.shutdown()
        patch_net.disconnect()
    dropped = {k: figures[k] for k in ("late_frames", "duplicate_frames", "out_of_order_frames",
                                       "malformed_frames", "incomplete_samples", "send_errors",
                                       "callback_errors", "api_dropped")}
    assert dropped == dict.fromkeys(dropped, 0), figures
    assert figures["frames_in"] == server.frames_sent  # every patch frame was used in time
    assert source.reader.frames == figures["frames_out"] == 7 * figures["samples"]
    least = 0.5 * DEFAULT_REFRESH_HZ * SECONDS
    assert stats.redraws >= least and drawn.stats.redraws >= least
    assert drawn.error is None
    read, called = bus_view.state().statuses, callback_view.state().statuses
    for node in scene.node_ids:
        samples = health[node].samples
        assert samples >= 0.8 * scene.rate_hz * SECONDS
        assert (read[node].samples, read[node].incomplete, read[node].partial) == (samples, 0, 0)
        assert (called[node].samples, called[node].incomplete) == (samples, 0)
