"""``skin run --record F``: the host records the buses it runs, and in an .mcap the force
samples it published, beside its data plane, never in its way.

Each bus is opened a second time for the recording (as candump beside the host would):
that socket hears every frame on the bus, the host's own (SYNC, force TPDOs, SDO) included,
which the host's socket does not take back (``canbus.rxfilter``). Its receive thread
appends each frame to the :class:`~canbus.tools.recorder.Recorder`'s queue; the host's
publishing thread appends each force sample (``HostManager.on_forces``); the recorder's
own thread writes both.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import can

    from canbus.master.host import HostManager
    from canbus.master.hostconfig import HostConfig
    from canbus.tools.recorder import Recorder


@dataclass
class HostRecording:
    recorder: Recorder
    samples: int = 0

    def on_forces(self, frame: Any) -> None:
        self.samples += 1
        self.recorder.on_forces(frame)


class _Named:
    """Gives each frame of one of several buses the bus's name as its channel."""

    def __init__(self, recorder: Recorder, name: str) -> None:
        self.recorder, self.name = recorder, name

    def on_message_received(self, msg: can.Message) -> None:
        msg.channel = self.name  # this bus handle is the recording's alone
        self.recorder.on_message_received(msg)

    def on_error(self, exc: Exception) -> None:
        pass

    def stop(self) -> None:
        pass


@contextlib.contextmanager
def recording(path: str, config: HostConfig, host: HostManager,
              rcvbuf: int = 0) -> Iterator[HostRecording]:
    """Record every bus of ``config`` to ``path`` while the block runs; the file is closed,
    complete, when it ends, however it ends."""
    from functools import partial

    from canbus.busio import ResilientBus
    from canbus.master.busconfig import open_bus
    from canbus.receiveloop import ReceiveLoop
    from canbus.tools.mcap_writer import placements
    from canbus.tools.recorder import Recorder, enlarge_receive_buffer, log_channel_name
    from skin.commands.common.logs import held_back

    several = len(config.buses) > 1
    channel = None if several else log_channel_name(config.buses[0].channel)
    recorder = Recorder(path, channel=channel,
                        placements=placements(config) if path.lower().endswith(".mcap")
                        else None)
    result = HostRecording(recorder)
    with ExitStack() as stack:
        stack.callback(recorder.stop)  # last: after every frame was handed to it
        for bus in config.buses:
            with held_back("can"):
                handle = ResilientBus(partial(open_bus, bus),
                                      name=f"recording {bus.name} ({bus.described})",
                                      prepare=partial(enlarge_receive_buffer, size=rcvbuf)
                                      if rcvbuf else None)
            stack.callback(handle.shutdown)
            listener = _Named(recorder, bus.name) if several else recorder
            loop = ReceiveLoop(handle, [listener], timeout=0.05, name=f"record {bus.name}")
            stack.callback(loop.stop)
        if recorder.takes_forces:
            host.on_forces(result.on_forces)
            stack.callback(host.remove_callback, result.on_forces)
        yield result
