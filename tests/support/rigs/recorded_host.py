"""A host run on a virtual channel, recorded: simulated patches on a canopen network of their
own, the host on a bus of its own, and recorders on a third, as separate devices would be.

    with recorded_host("ch", config, ArraySource(r, (1, 2)), [Recorder(path)]) as run:
        wait_until(lambda: len(run.frames) >= 100, what="force frames")
    run.stats  # the host's counters, once stopped; the recording is saved
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field

import can
import canopen

from canbus.device.patch_server import PatchServer
from canbus.device.source import ArraySource
from canbus.master.dataplane import ForceFrame
from canbus.master.events import HostEvent
from canbus.master.host import HostManager
from canbus.master.hostconfig import HostConfig


@dataclass
class HostRecording:
    """The running host, every force frame it published, and its counters once stopped."""

    host: HostManager
    frames: list[ForceFrame] = field(default_factory=list)
    stats: dict[str, int] = field(default_factory=dict)


@contextlib.contextmanager
def recorded_host(channel: str, config: HostConfig, source: ArraySource,
                  recorders: Sequence[can.Listener],
                  on_event: Callable[[HostEvent], None] | None = None
                  ) -> Iterator[HostRecording]:
    """The host started and operational, its frames kept; on leaving, the host, the patches
    and the recorders stop (the recorders' notifier saves them)."""
    listen = can.Bus(interface="virtual", channel=channel)
    notifier = can.Notifier(listen, list(recorders), timeout=0.05)
    device = canopen.Network()
    device.NOTIFIER_CYCLE = 0.05
    device.connect(interface="virtual", channel=channel)
    bus = can.Bus(interface="virtual", channel=channel)
    try:
        with PatchServer(device, source):
            run = HostRecording(HostManager(bus, config))
            run.host.on_forces(run.frames.append)
            if on_event is not None:
                run.host.on_event(on_event)
            run.host.start()
            try:
                assert run.host.wait_operational(timeout=15.0), run.host.health()
                yield run
            finally:
                run.host.stop()
                run.stats = run.host.stats()
    finally:
        device.disconnect()
        notifier.stop(timeout=1.0)
        listen.shutdown()
        bus.shutdown()
