"""A recording in a process of its own, beside the host (``skin run --record``): it opens
each bus again, as candump beside the host would, records every frame, and takes the
force samples the host published over a pipe (``canbus.tools.sample_wire``, 320 bytes
each), so that neither the second receive path nor the writer shares the host's GIL.

The parent (:class:`RecordingProcess`) queues each sample on the host's publishing thread
(an append) and a thread of its own packs and writes them to the pipe every 10 ms. The
child ignores SIGINT, SIGTERM and SIGHUP (the host's signals, sent to the whole process
group by a terminal) and ends when its stdin ends: the parent closes it when it stops,
and the kernel closes it when the parent dies, so a kill -9 of the host still leaves a
complete, indexed recording (less the samples of its last 10 ms).

Protocol on the child's stdout, one JSON object a line: ``{"ready": true}`` once the file
and the buses are open, or ``{"error": "..."}`` (one line naming what is wrong), and at
the end ``{"frames": N, "samples": M, "error": null | "..."}``.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
from collections import deque
from collections.abc import Sequence
from dataclasses import asdict
from typing import IO, TYPE_CHECKING, Any

from skin.errors import ConfigError, SkinError

if TYPE_CHECKING:
    from canbus.master.busconfig import BusConfig
    from canbus.master.channel import ForceFrame
    from canbus.tools.mcap_messages import Placement

_POLL_S = 0.01
IN_PROCESS = ("virtual", "timed")
"""Interfaces a second process cannot hear: their recording stays in the host's process."""


class RecordingProcess:
    """Record ``buses`` to ``path`` in a child process until :meth:`stop`."""

    def __init__(self, path: str, buses: Sequence[BusConfig], *, channel: str | None,
                 placements: list[Placement] | None, rcvbuf: int = 0) -> None:
        spec = {"path": path, "channel": channel, "rcvbuf": rcvbuf,
                "buses": [_bus_json(b) for b in buses],
                "placements": [asdict(p) for p in placements or []]}
        self.path = path
        self.samples = 0
        self.frames = 0
        self._pending: deque[ForceFrame] = deque()
        self._stopping = threading.Event()
        self._finished = False
        self.error: str | None = None
        self._child = subprocess.Popen(
            [sys.executable, "-m", "skin.commands.common.recordproc", json.dumps(spec)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        assert self._child.stdin is not None and self._child.stdout is not None
        self._stdin: IO[bytes] = self._child.stdin
        self._stdout: IO[bytes] = self._child.stdout
        first = _line(self._stdout)
        if not first.get("ready"):
            self._child.wait()
            raise SkinError(str(first.get("error") or "the recording process ended at once"))
        self._thread = threading.Thread(target=self._forward, name="recording pipe",
                                        daemon=True)
        self._thread.start()

    def on_forces(self, frame: ForceFrame) -> None:
        """A ``HostManager.on_forces`` callback: an append, never a wait."""
        self._pending.append(frame)
        self.samples += 1

    def _forward(self) -> None:
        from canbus.tools import sample_wire

        pending = self._pending
        while True:
            stopping = self._stopping.wait(_POLL_S)
            batch = [sample_wire.pack(pending.popleft()) for _ in range(len(pending))]
            if batch and self.error is None:
                try:
                    self._stdin.write(b"".join(batch))
                    self._stdin.flush()
                except OSError as err:  # the child is gone: its error says why
                    self.error = f"the recording process stopped taking samples ({err})"
            if stopping:
                return

    def stop(self, timeout: float = 60.0) -> None:
        """Hand over what is queued, end the child's input and wait for it to close the
        file; OSError naming the file if the recording failed (idempotent)."""
        if self._finished:
            return
        self._finished = True
        self._stopping.set()
        self._thread.join()
        with contextlib.suppress(OSError):
            self._stdin.close()
        try:
            self._child.wait(timeout)
        except subprocess.TimeoutExpired:
            self._child.kill()
            self._child.wait()
        last = _line(self._stdout)
        self._stdout.close()
        self.frames = int(last.get("frames") or 0)
        error = last.get("error") or self.error
        if error is None and self._child.returncode != 0:
            error = f"the recording process ended with status {self._child.returncode}"
        if error is not None:
            raise OSError(f"recording to {self.path} failed: {error}")


def _bus_json(bus: BusConfig) -> dict[str, Any]:
    out = asdict(bus)
    out["options"] = dict(bus.options)
    return out


def _line(stream: IO[bytes]) -> dict[str, Any]:
    """The last JSON line the child wrote so far (reading to its next line)."""
    raw = stream.readline()
    try:
        value = json.loads(raw) if raw.strip() else {}
    except ValueError:
        value = {"error": raw.decode(errors="replace").strip()}
    return value if isinstance(value, dict) else {}


def _say(**fields: Any) -> None:
    sys.stdout.write(json.dumps(fields) + "\n")
    sys.stdout.flush()


def _child(spec: dict[str, Any]) -> int:
    """The child: record until stdin ends."""
    from contextlib import ExitStack
    from functools import partial

    from canbus.busio import ResilientBus
    from canbus.master.busconfig import BusConfig, open_bus
    from canbus.receiveloop import ReceiveLoop
    from canbus.rxbuffer import enlarge_receive_buffer
    from canbus.tools import sample_wire
    from canbus.tools.mcap_messages import Placement
    from canbus.tools.recorder import Recorder

    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)
    buses = [BusConfig(**b) for b in spec["buses"]]
    placements = [Placement(**{**p, "position_m": tuple(p["position_m"])})
                  for p in spec["placements"]]
    rcvbuf = int(spec["rcvbuf"])
    samples = 0
    try:
        recorder = Recorder(spec["path"], channel=spec["channel"], placements=placements or None)
    except (SkinError, OSError) as err:
        _say(error=str(err))
        return 1
    with ExitStack() as stack:
        stack.callback(recorder.stop)
        try:
            for bus in buses:
                handle = ResilientBus(partial(open_bus, bus), name=f"recording {bus.name}",
                                      prepare=partial(enlarge_receive_buffer, size=rcvbuf)
                                      if rcvbuf else None)
                stack.callback(handle.shutdown)
                listener: Any = recorder if len(buses) == 1 else NamedFrames(recorder, bus.name)
                loop = ReceiveLoop(handle, [listener], timeout=0.05, name=f"record {bus.name}")
                stack.callback(loop.stop)
        except (SkinError, OSError) as err:
            _say(error=str(err))
            return 1
        _say(ready=True)
        stdin = sys.stdin.buffer
        while len(data := stdin.read(sample_wire.SIZE)) == sample_wire.SIZE:
            recorder.on_forces(*sample_wire.unpack(data))
            samples += 1
    _say(frames=recorder.written, samples=samples, error=None)
    return 0


class NamedFrames:
    """Gives each frame of one of several buses the bus's name as its channel."""

    def __init__(self, recorder: Any, name: str) -> None:
        self.recorder, self.name = recorder, name

    def on_message_received(self, msg: Any) -> None:
        msg.channel = self.name  # this bus handle is the recording's alone
        self.recorder.on_message_received(msg)

    def on_error(self, exc: Exception) -> None:
        pass

    def stop(self) -> None:
        pass


def main() -> None:
    try:
        code = _child(json.loads(sys.argv[1]))
    except (SkinError, OSError, ConfigError) as err:  # closing the file failed
        _say(frames=0, samples=0, error=str(err))
        code = 1
    os._exit(code)  # no atexit of libraries that may wait on the buses


if __name__ == "__main__":
    main()

