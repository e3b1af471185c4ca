"""Replay a recording (read and checked by :class:`canbus.tools.recording.Recording`) onto
a bus.

:class:`Replayer` sends a recording with its original timing (python-can's ``MessageSync``)
or fast: as fast as the bus takes it, or paced to at most ``rate_fps`` frames per second
(a transport without flow control, such as udp_multicast, drops what its receivers
cannot take in time); once, N times or until stopped. The bus stamps what it
sends (a virtual bus with its send time unless built with ``preserve_timestamps``), so a
receiver sees the replay's time, as it would see a live bus's. To decode a recording,
replay it to a listen-only host (``skin run CONFIG --listen-only``): it follows the
recorded SYNCs, NMT commands, heartbeats and EMCYs and gives back the recorded run's
forces.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import can

from canbus.tools.recording import Recording, recording_reader
from skin.errors import ConfigError, RecordingError

__all__ = ["ReplayResult", "Replayer"]


@dataclass(frozen=True)
class ReplayResult:
    frames_sent: int
    error_frames_skipped: int
    passes: int
    seconds: float


def _outgoing(msg: can.Message) -> can.Message:
    return can.Message(
        timestamp=msg.timestamp, arbitration_id=msg.arbitration_id,
        is_extended_id=msg.is_extended_id, is_remote_frame=msg.is_remote_frame,
        is_error_frame=msg.is_error_frame, is_fd=msg.is_fd, bitrate_switch=msg.bitrate_switch,
        error_state_indicator=msg.error_state_indicator, dlc=msg.dlc, data=msg.data,
        is_rx=False)


class Replayer:
    """Sends ``path`` onto ``bus``: ``passes`` times (0: until stopped), checked as it goes.

    ``realtime`` keeps the recorded intervals (python-can's ``MessageSync``; pauses longer
    than ``skip_s`` are cut to it); otherwise frames go as fast as ``bus.send`` takes
    them. Error frames are sent only with ``error_frames`` (most interfaces cannot).
    ``partial`` replays a recording with a cut tail (see :class:`Recording`). The
    counters are live, so a caller still knows what was sent when a damaged frame stops
    the replay with RecordingError.
    """

    def __init__(self, bus: can.BusABC, path: str | os.PathLike[str], *, realtime: bool = True,
                 passes: int = 1, skip_s: float = 60.0, error_frames: bool = False,
                 rate_fps: float | None = None, partial: bool = False) -> None:
        recording_reader(path)
        if rate_fps is not None and not (math.isfinite(rate_fps) and rate_fps > 0):
            raise ConfigError("rate_fps", f"must be a positive number of frames/s, got {rate_fps}")
        self.bus, self.path = bus, path
        self.realtime, self.passes, self.skip_s = realtime, passes, skip_s
        self.rate_fps = None if realtime else rate_fps
        self.error_frames = error_frames
        self.partial = partial
        self.cut: RecordingError | None = None
        self.sent = self.skipped = self.done = 0
        self._started: float | None = None

    def run(self, stop: threading.Event | None = None,
            on_pass: Callable[[int, int], Any] | None = None) -> ReplayResult:
        """Replay until the passes are done or ``stop`` is set; ``on_pass(pass, frames)``."""
        self._started = time.monotonic()
        pace = _Pace(self.rate_fps)
        while self.passes == 0 or self.done < self.passes:
            with Recording(self.path, partial=self.partial) as recording:
                messages: Any = recording if not self.realtime else \
                    can.MessageSync(recording, timestamps=True, skip=self.skip_s)
                for msg in messages:
                    if stop is not None and stop.is_set():
                        return self.result()
                    if msg.is_error_frame and not self.error_frames:
                        self.skipped += 1
                        continue
                    pace.wait(stop)
                    self.bus.send(_outgoing(msg))
                    self.sent += 1
            self.cut = recording.cut
            self.done += 1
            if on_pass is not None:
                on_pass(self.done, recording.frames)
            if recording.frames == 0:
                break  # an empty recording would loop for ever without sending anything
        return self.result()

    def result(self) -> ReplayResult:
        """What has been sent so far (also after a stop or an error)."""
        seconds = 0.0 if self._started is None else time.monotonic() - self._started
        return ReplayResult(self.sent, self.skipped, self.done, seconds)


class _Pace:
    """At most ``rate_fps`` frames per second on an absolute schedule (no drift), sleeping
    only when ahead by a millisecond or more: a sleep per frame would oversleep."""

    AHEAD_S = 0.001

    def __init__(self, rate_fps: float | None) -> None:
        self.period = 0.0 if rate_fps is None else 1.0 / rate_fps
        self.due = time.monotonic()

    def wait(self, stop: threading.Event | None) -> None:
        if not self.period:
            return
        now = time.monotonic()
        self.due = max(self.due + self.period, now - self.AHEAD_S)  # no burst after a stall
        ahead = self.due - now
        if ahead >= self.AHEAD_S:
            if stop is None:
                time.sleep(ahead)
            else:
                stop.wait(ahead)

