"""What the live view costs: `python -m tests.support.view [RUNS] [SECONDS]`.

1. The host's own counters with and without the view, in interleaved runs of ``skin
   demo``'s set-up (8 simulated patches of the indenter scene at 100 Hz, the host, one
   process, threads free on every CPU): late, duplicate and incomplete counts, and the
   process's CPU time per second of run. With the view: a ``ForceReader`` listening on the
   simulated patches' bus, which receives every force PDO anyway (as ``skin demo``'s bus
   clock does: a bus of its own would copy every frame once more), drawn by ``draw_live``,
   and ``SkinView.update`` as the host's callback drawn by a ``LiveThread`` (how ``skin
   demo`` shows the view), both at the default 4 redraws/s.
2. One redraw (build + rich drawing into a 200-column console) of 8 and of 64 patches,
   and the reader's time per force sample (8 force nodes, 7 classic PDOs each), against
   the 10 ms period of a 100 Hz skin.
"""

from __future__ import annotations

import gc
import io
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import can
import canopen
import numpy as np
from rich.console import Console
from rich.live import Live

from canbus.device.patch_server import PatchServer
from canbus.device.source import ArraySource
from canbus.master.forcenode import ForceNode
from canbus.master.host import HostManager
from canbus.master.hostconfig import HostConfig, PatchConfig
from canbus.tools.forcereader import ForceReader
from sim import Simulator
from skin.commands.demo import demo_scene
from skin.commands.view.layout import Layout, layout_from_positions
from skin.commands.view.live import LiveThread, draw_live
from skin.commands.view.term import SkinView

PATCHES = 8


def _console() -> Console:
    return Console(file=io.StringIO(), force_terminal=True, color_system="truecolor",
                   width=200, height=60)


def host_run(with_view: bool, seconds: float, k: int, resistance: np.ndarray,
             node_ids: tuple[int, ...], layout: Layout) -> dict[str, float]:
    config = HostConfig(patches=tuple(PatchConfig(n) for n in node_ids), sync_period_ms=10.0,
                        scan_ms=100).check()
    channel = f"bench-view-{k}"
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05
    net.connect(interface="virtual", channel=channel)
    host_bus = can.Bus(interface="virtual", channel=channel)
    server = PatchServer(net, ArraySource(resistance, node_ids))
    host = HostManager(host_bus, config)
    bus_view, callback_view = SkinView(layout), SkinView(layout)
    reader = ForceReader()
    if with_view:
        host.on_forces(callback_view.update)
        reader.on_sample(bus_view.update)
        reader.start()
        assert net.notifier is not None
        net.notifier.add_listener(reader)
    gc.collect()
    gc.freeze()
    try:
        with server, host:
            host.wait_operational(timeout=10.0)
            started, cpu = time.monotonic(), time.process_time()
            if with_view:
                with LiveThread(callback_view, console=_console()):
                    draw_live(bus_view, lambda: time.monotonic() - started > seconds,
                              console=_console())
            else:
                time.sleep(seconds)
            cpu = (time.process_time() - cpu) / (time.monotonic() - started)
        stats = host.stats()
    finally:
        gc.unfreeze()
        host_bus.shutdown()
        net.disconnect()
        reader.stop()
    return {"late": stats["late_frames"], "duplicate": stats["duplicate_frames"],
            "incomplete": stats["incomplete_samples"], "samples": stats["samples"],
            "cpu": cpu, "read": reader.samples}


def redraw_ms(patches: int) -> float:
    side = int(np.ceil(np.sqrt(patches)))
    layout = Layout({n + 1: (0.05 * (n % side), 0.05 * (n // side)) for n in range(patches)})
    view = SkinView(layout)
    reader = ForceReader([65 + n for n in range(min(patches, 63))])
    reader.on_sample(view.update)
    rng = np.random.default_rng(0)
    for n in range(min(patches, 63)):
        node = ForceNode(65 + n, n + 1)
        reader.feed([can.Message(arbitration_id=cob, data=data, timestamp=1.0,
                                 is_extended_id=False)
                     for cob, data in node.frames(rng.uniform(0, 4, (9, 3)), np.ones(9, bool),
                                                  True)])
    times = []
    with Live(console=_console(), auto_refresh=False) as live:
        for _ in range(30):
            start = time.perf_counter()
            live.update(view.renderable(1.0), refresh=True)
            times.append(time.perf_counter() - start)
    return 1000.0 * statistics.median(times)


def reader_us_per_sample() -> float:
    nodes = [ForceNode(65 + n, n + 1) for n in range(PATCHES)]
    reader = ForceReader([65 + n for n in range(PATCHES)])
    rng = np.random.default_rng(1)
    messages = []
    for cycle in range(200):
        for node in nodes:
            messages += [can.Message(arbitration_id=cob, data=data, timestamp=0.01 * cycle,
                                     is_extended_id=False)
                         for cob, data in node.frames(rng.uniform(0, 4, (9, 3)),
                                                      np.ones(9, bool), True)]
    best = []
    for _ in range(3):
        start = time.perf_counter()
        for k in range(0, len(messages), 5 * 7 * PATCHES):  # 50 ms of frames per round
            for msg in messages[k:k + 5 * 7 * PATCHES]:
                reader.on_message_received(msg)
            reader.process()
        best.append((time.perf_counter() - start) / (200 * PATCHES))
    return 1e6 * min(best)


def main() -> None:
    runs = int(sys.argv[1]) if len(sys.argv) > 1 else 4
    seconds = float(sys.argv[2]) if len(sys.argv) > 2 else 5.0
    scene = demo_scene("indenter", PATCHES)
    resistance = Simulator(scene).run(int(seconds * 100) + 300).resistance_ohm
    layout = layout_from_positions({p.node_id: p.position_m for p in scene.patches}, "scene")
    rows: dict[bool, list[dict[str, float]]] = {True: [], False: []}
    for k in range(runs):
        for with_view in (True, False):
            row = host_run(with_view, seconds, 2 * k + with_view, resistance, scene.node_ids,
                           layout)
            rows[with_view].append(row)
            print(f"{'view   ' if with_view else 'no view'} {row}", flush=True)
    for with_view, label in ((False, "without the view"), (True, "with both views")):
        r = rows[with_view]
        print(f"{label}: late {[x['late'] for x in r]}, duplicate "
              f"{[x['duplicate'] for x in r]}, incomplete {[x['incomplete'] for x in r]}, "
              f"CPU {min(x['cpu'] for x in r):.0%}..{max(x['cpu'] for x in r):.0%} of a core")
    print(f"one redraw: 8 patches {redraw_ms(8):.2f} ms, 64 patches {redraw_ms(64):.2f} ms "
          "(the period of 100 Hz: 10 ms)")
    print(f"reader: {reader_us_per_sample():.1f} µs per force sample (7 PDOs), 8 patches")


if __name__ == "__main__":
    main()
