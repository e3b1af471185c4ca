"""The data plane's whole threaded path: python-can's ``Notifier`` delivering from a
virtual bus (:func:`notifier_rate`), and a bus -> ``Notifier`` -> data plane with its
publishing thread (:func:`pipeline_rate`), its receive side timed on its own threads' CPU
clocks (:class:`ReceiveSideClock`), the sender in the same process apart."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import can

from canbus.master.contact import PatchContact
from canbus.master.dataplane import ForceFrame
from decoder.protocol import Decoder
from skin.benchmarks.dataplane_rigs import DataPlaneRig, Stream
from skin.errors import BusError


class QueuedFrames:
    """``frames`` frames waiting on a virtual bus for a python-can ``Notifier`` to deliver."""

    def __init__(self, frames: int) -> None:
        self.frames = frames
        channel = f"dataplane-bench-{id(self)}"
        self.sender = can.Bus(interface="virtual", channel=channel)
        self.receiver = can.Bus(interface="virtual", channel=channel)
        self.notifier: can.Notifier | None = None
        msg = can.Message(arbitration_id=0x181, data=bytes(8), is_extended_id=False)
        for _ in range(frames):
            self.sender.send(msg)

    def deliver(self) -> float:
        """Seconds for a ``Notifier`` to hand every queued frame to a listener."""
        done = threading.Event()
        count = 0

        def on_message(msg: can.Message) -> None:
            nonlocal count
            count += 1
            if count == self.frames:
                done.set()

        start = time.perf_counter()
        self.notifier = can.Notifier(self.receiver, [on_message], timeout=0.05)
        finished = done.wait(60.0)
        elapsed = time.perf_counter() - start
        if not finished:
            raise BusError(f"the notifier delivered {count} of {self.frames} frames")
        return elapsed

    def close(self) -> None:
        """Stop the notifier (it may wait out its ``recv`` time-out) and the buses."""
        if self.notifier is not None:
            self.notifier.stop(timeout=1.0)
        self.sender.shutdown()
        self.receiver.shutdown()


def notifier_rate(frames: int = 20_000) -> float:
    """Frames/s a ``Notifier`` takes from a virtual bus to a listener (``bus.recv`` and
    dispatch; the frames are queued beforehand, so the sender's share is not counted)."""
    queued = QueuedFrames(frames)
    try:
        return frames / queued.deliver()
    finally:
        queued.close()


def notifier_threads(bus: can.BusABC) -> list[str]:
    """The name python-can gives the receive thread of a ``Notifier`` on ``bus``."""
    return [f'Notifier for bus "{bus.channel_info}"']


class ReceiveSideClock:
    """The CPU time the named threads (the receive side: the Notifier's thread, the data
    plane's) spend from now on, read from each thread's own CPU clock: the sender in the
    same process, and the GIL it holds, are not counted."""

    def __init__(self, names: list[str]) -> None:
        threads = {t.name: t for t in threading.enumerate()}
        missing = [name for name in names if name not in threads]
        if missing:
            raise BusError(f"no thread named {missing} to time")
        self.clocks = [time.pthread_getcpuclockid(threads[n].ident or 0) for n in names]
        self.start = [time.clock_gettime(c) for c in self.clocks]

    def seconds(self) -> float:
        return sum(time.clock_gettime(c) - s for c, s in zip(self.clocks, self.start,
                                                               strict=True))


def pipeline_rate(stream: Stream, decoder: Decoder,
                  contact: Callable[[int], PatchContact] | None = None, *,
                  bus: dict[str, Any] | None = None, recorder: Any = None,
                  pace: float | None = None) -> dict[str, float]:
    """The whole path in one process: a bus -> ``Notifier`` -> data plane (its thread).

    The sender opens each cycle (``on_sync``), sends its frames and waits until the data
    plane has taken them all before the next SYNC, as a SYNC-paced bus would. ``bus``:
    python-can's arguments of the bus (default: a virtual channel of its own).
    ``recorder``: a recorder beside it, as ``skin run --record`` runs one, given every
    sample the publisher hands out (``on_forces``); a ``can.Listener`` (an in-process
    :class:`~canbus.tools.recorder.Recorder`) also gets the frames from a bus of its own.
    ``pace``: frames/s at most, each cycle sent at its time (a bus's rate, not the most).
    """
    bus = bus or {"interface": "virtual", "channel": f"dataplane-pipeline-{id(stream)}"}
    from canbus.rxbuffer import DEFAULT_RCVBUF, enlarge_receive_buffer

    sender = can.Bus(**bus)
    receiver = can.Bus(**bus)
    enlarge_receive_buffer(receiver, DEFAULT_RCVBUF)  # as the commands do (a socket bus)
    rig = DataPlaneRig(stream, decoder, background=True, window_s=0.0, contact=contact)
    notifier = can.Notifier(receiver, [rig.plane], timeout=0.05)
    receiving = ReceiveSideClock([*notifier_threads(receiver), "dataplane"])
    tap = None
    if isinstance(recorder, can.Listener):
        tapped = can.Bus(**bus)
        enlarge_receive_buffer(tapped, DEFAULT_RCVBUF)
        tap = can.Notifier(tapped, [recorder], timeout=0.05)
    if recorder is not None:

        def record(batch: list[ForceFrame]) -> None:
            for frame in batch:
                recorder.on_forces(frame)

        rig.plane.subscribe(record)
    per_cycle = len(stream.frames[0])
    try:
        start = time.perf_counter()
        for k, frames in enumerate(stream.frames):
            if pace is not None:
                due = start + k * per_cycle / pace
                time.sleep(max(0.0, due - time.perf_counter()))
            rig.plane.on_sync(k + 1, 0, time.time())
            for msg in frames:
                sender.send(msg)
            deadline = time.monotonic() + 10.0
            while rig.plane.stats.frames_in < (k + 1) * per_cycle:
                if time.monotonic() > deadline:
                    raise BusError(f"the data plane took {rig.plane.stats.frames_in} of "
                                   f"{(k + 1) * per_cycle} frames")
                time.sleep(50e-6)
        rig.plane.flush()
        elapsed = time.perf_counter() - start
        receive_cpu = receiving.seconds()
        stats = rig.plane.stats.snapshot()
    finally:
        notifier.stop(timeout=1.0)
        if tap is not None:
            tap.stop(timeout=1.0)  # and the recorder: written out and closed
            tap.bus.shutdown()  # type: ignore[union-attr]
        sender.shutdown()
        receiver.shutdown()
        rig.close()
    return {"frames_per_s": stats["frames_in"] / elapsed,
            "receive_frames_per_cpu_s": stats["frames_in"] / max(receive_cpu, 1e-9),
            "complete": float(stats["complete_samples"] == stats["samples"]),
            "mean_batch": stats["samples"] / max(stats["batches"], 1)}
