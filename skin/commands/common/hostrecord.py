"""``skin run --record F``: the host records the buses it runs, and in an .mcap the force
samples it published, beside its data plane, never in its way.

Each bus is opened a second time for the recording (as candump beside the host would):
that handle hears every frame on the bus, the host's own (SYNC, force TPDOs, SDO)
included, which the host's socket does not take back (``canbus.rxfilter``). On a bus other
processes can hear, the recording runs in a process of its own
(:mod:`skin.commands.common.recordproc`: no second receive path, no writer in the host's GIL; the
samples cross a pipe); on an in-process bus (virtual, timed) in a
:class:`~canbus.tools.recorder.Recorder` thread of the host's process.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from contextlib import ExitStack
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from canbus.master.host import HostManager
    from canbus.master.hostconfig import HostConfig
    from canbus.tools.recorder import Recorder


class HostRecording:
    """What the host recorded: :attr:`frames` (once stopped) and :attr:`samples`."""

    def __init__(self, takes_forces: bool) -> None:
        self.takes_forces = takes_forces
        self.samples = 0
        self.frames = 0

    def summary(self, path: str) -> str:
        samples = f" and {self.samples} samples" if self.takes_forces else ""
        return f"recorded {self.frames:,} frames{samples} to {path}"

    def as_json(self, path: str) -> dict[str, object]:
        return {"path": path, "frames": self.frames, "samples": self.samples}


@contextlib.contextmanager
def recording(path: str, config: HostConfig, host: HostManager,
              rcvbuf: int = 0) -> Iterator[HostRecording]:
    """Record every bus of ``config`` to ``path`` while the block runs; the file is closed,
    complete, when it ends, however it ends."""
    from canbus.offline.mcap import placements
    from canbus.tools.recorder import log_channel_name, recording_format
    from skin.commands.common.recordproc import IN_PROCESS, RecordingProcess

    mcap = recording_format(path) == ".mcap"
    channel = None if len(config.buses) > 1 else log_channel_name(config.buses[0].channel)
    places = placements(config) if mcap else None
    result = HostRecording(mcap)
    if any(bus.interface in IN_PROCESS for bus in config.buses):
        with _in_process(path, config, host, channel, places, rcvbuf, result):
            yield result
        return
    child = RecordingProcess(path, config.buses, channel=channel, placements=places,
                             rcvbuf=rcvbuf)
    try:
        if mcap:
            host.on_forces(child.on_forces)
        try:
            yield result
        finally:
            if mcap:
                host.remove_callback(child.on_forces)
    finally:
        result.samples = child.samples
        child.stop()
        result.frames = child.frames


@contextlib.contextmanager
def _in_process(path: str, config: HostConfig, host: HostManager, channel: str | None,
                places: Any, rcvbuf: int, result: HostRecording) -> Iterator[None]:
    from canbus.receiveloop import ReceiveLoop
    from canbus.tools.recorder import Recorder
    from skin.commands.common.hostbus import open_resilient
    from skin.commands.common.recordproc import NamedFrames

    recorder = Recorder(path, channel=channel, placements=places)

    def on_forces(frame: Any) -> None:
        result.samples += 1
        recorder.on_forces(frame)

    with ExitStack() as stack:
        stack.callback(_stopped, recorder, result)  # last: after every frame was handed on
        for bus in config.buses:
            handle = open_resilient(bus, rcvbuf,
                                    name=f"recording {bus.name} ({bus.described})")
            stack.callback(handle.shutdown)
            listener = NamedFrames(recorder, bus.name) if len(config.buses) > 1 else recorder
            loop = ReceiveLoop(handle, [listener], timeout=0.05, name=f"record {bus.name}")
            stack.callback(loop.stop)
        if recorder.takes_forces:
            host.on_forces(on_forces)
            stack.callback(host.remove_callback, on_forces)
        yield


def _stopped(recorder: Recorder, result: HostRecording) -> None:
    recorder.stop()
    result.frames = recorder.written
