"""Forces out of a recording, without a bus: a listen-only host fed the recording.

:func:`decode_recording` plays a recording (.log, .asc, .blf, .pcap, .pcapng, .mcap) through the
very host a listen-only ``skin run`` is (:class:`~canbus.master.host.HostManager` with the
:class:`~canbus.master.follower.ListenOnly` policy), as fast as it can take the frames and
on the recording's own clock: every frame keeps its recorded timestamp (the data plane's
SYNC windows judge those), and the heartbeat consumer's clock is the timestamp of the
frame being read, so a patch that fell silent in the recording is lost in the decode just
as it was on the bus. The result does not depend on the machine, its load or the speed
of the decode: the same recording decodes to the same forces every time.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can

from canbus.master.dataplane import ForceFrame
from canbus.master.host import HostManager
from canbus.master.hostconfig import HostConfig
from canbus.master.rawsample import RawSubscriber
from canbus.tools.recording import Recording
from skin.errors import BusError


class RecordingBus(can.BusABC):
    """A recording as a bus that only receives, each frame with its recorded timestamp.

    ``on_frame(timestamp)`` runs as each frame is read, before it is handed on, and
    ``after_frame()`` once it has been (when the next one is asked for: a notifier asks
    only then). :attr:`finished` is set once every frame was handed on.
    """

    def __init__(self, path: str | os.PathLike[str], *,
                 on_frame: Callable[[float], None] | None = None,
                 after_frame: Callable[[], None] | None = None, **kwargs: Any) -> None:
        self.recording = Recording(path)
        self._frames = iter(self.recording)
        self.on_frame, self.after_frame = on_frame, after_frame
        self.finished = threading.Event()
        self._closed = threading.Event()
        self._last: float | None = None
        self.error: BaseException | None = None
        self.channel_info = f"recording {os.fspath(path)}"
        super().__init__(channel=os.fspath(path), **kwargs)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self.finished.is_set():  # nothing more to read: idle, as a quiet bus would
            self._closed.wait(timeout)
            return None, False
        if self._last is not None and self.after_frame is not None:
            self.after_frame()
        try:
            msg = next(self._frames)
        except StopIteration:
            self.finished.set()
            return None, False
        except BaseException as err:  # a damaged file: kept for the caller, reading stops
            self.error = err
            self.finished.set()
            return None, False
        self._last = msg.timestamp
        if self.on_frame is not None:
            self.on_frame(msg.timestamp)
        return msg, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        raise can.CanOperationError("a recording is only read: nothing is sent to it")

    def shutdown(self) -> None:
        self._closed.set()
        self.recording.close()
        super().shutdown()


def decode_recording(path: str | os.PathLike[str], config: HostConfig, *,
                     on_frame: Callable[[ForceFrame], None] | None = None,
                     on_raw: RawSubscriber | None = None) -> list[ForceFrame]:
    """Every force sample a listen-only host publishes for the recording at ``path``, in
    the order it publishes them. ``config``'s buses: one (the recording is its bus).
    ``on_raw``: given each published batch's raw samples (the resistances as the patches
    sent them, :mod:`canbus.master.rawsample`).

    Raises :class:`~skin.errors.RecordingError` for a damaged recording (after decoding
    what comes before the damaged frame), :class:`~skin.errors.BusError` for a config
    with several buses.
    """
    if len(config.buses) != 1:
        raise BusError(f"a recording is one bus; the config has {len(config.buses)}")
    now = [0.0]
    frames: list[ForceFrame] = []
    host: HostManager | None = None

    def at(timestamp: float) -> None:
        now[0] = timestamp

    def check() -> None:  # a live host's heartbeat consumer, at this frame's time
        if host is not None:
            for link in host.links.values():
                link.monitor.check()

    bus = RecordingBus(Path(path), on_frame=at, after_frame=check)
    try:
        host = HostManager(bus, config, listen_only=True, clock=lambda: now[0])
        host.on_forces(frames.append)
        if on_frame is not None:
            host.on_forces(on_frame)
        if on_raw is not None:
            host.on_raw_samples(on_raw)
        with host:  # the notifier asks for the next frame only once it handed this one on
            bus.finished.wait()
    finally:
        bus.shutdown()
    if bus.error is not None:
        raise bus.error
    return frames

