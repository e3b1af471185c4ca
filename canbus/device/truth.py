"""The simulator's true forces, written as reference forces while its patches answer SYNC.

``skin sim run SCENE --truth F.csv``: each SYNC steps the simulator once
(:class:`TruthSource`, read by the patch server inside its SYNC handler), and
:class:`TruthLog`, subscribed to SYNC after the server, writes the true force of that
step for every patch that answered (OPERATIONAL), keyed by the SYNC's counter and its
timestamp: the reference format of :mod:`skin.reference`. A calibration of the scene's
patches can then be tested end to end without hardware (docs/calibrate.md).

An answer the server sent more than half a SYNC period after the SYNC arrived (a busy
machine held its thread up) gets no truth: on a classic CAN bus it may arrive after the
next SYNC, where a host cannot tell it from that SYNC's answer (docs/host.md), and the
truth of one step would join the readings of another. Those are counted (``late``).
"""

from __future__ import annotations

import contextlib
import os
import statistics
import threading
import time
from collections import deque
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING

import canopen
import numpy as np
from numpy.typing import NDArray

from canbus.device.nmt_slave import OPERATIONAL
from canbus.device.patch_node import PatchNode
from skin.reference import ReferenceWriter

if TYPE_CHECKING:
    from sim import Simulator

SYNC_COB_ID = 0x080
BATCH = 50
LATE_FRACTION = 0.5
"""An answer sent later than this fraction of the SYNC period after its SYNC gets no truth."""


class TruthSource:
    """A simulator as a patch server's source that keeps the true force of the step it
    served last (``force_N``: (patches, 9, 3), before any effect).

    Steps are computed :data:`BATCH` at a time (one vectorised ``run``, about 60x cheaper
    per step than one ``step`` each) and served one per read: the same steps, since a
    simulator's ``run(a)`` then ``run(b)`` is ``run(a + b)`` (docs/sim.md), without the
    cost of a whole step in every SYNC's answer."""

    def __init__(self, simulator: Simulator) -> None:
        self.simulator = simulator
        self.node_ids = tuple(int(n) for n in simulator.node_ids)
        self.pillars = int(simulator.pillars)
        self.force_N: NDArray[np.float64] = np.zeros((len(self.node_ids), 9, 3))
        self.steps = 0
        self._resistance: NDArray[np.float64] = np.zeros((0, len(self.node_ids), 9, 1))
        self._force: NDArray[np.float64] = np.zeros((0, len(self.node_ids), 9, 3))
        self._next = 0

    def read(self) -> NDArray[np.float64]:
        if self._next == len(self._force):
            frame = self.simulator.run(BATCH)
            self._resistance = np.asarray(frame.resistance_ohm, dtype=np.float64)
            self._force = np.asarray(frame.force_N, dtype=np.float64)
            self._next = 0
        k, self._next = self._next, self._next + 1
        self.force_N = self._force[k]
        self.steps += 1
        sample: NDArray[np.float64] = self._resistance[k]
        return sample


class TruthLog:
    """Writes the true force of every SYNC's answer (see the module docstring)."""

    def __init__(self, path: str | os.PathLike[str], source: TruthSource,
                 nodes: Sequence[PatchNode]) -> None:
        self.source = source
        self.nodes = list(nodes)
        self.writer = ReferenceWriter(path)
        self._lock = threading.Lock()
        self._intervals: deque[float] = deque(maxlen=16)
        self._last: float | None = None
        self.late = 0  # answers left without truth (see the module docstring)

    def on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """After the server's own SYNC handler: it has read this SYNC's step and answered."""
        answered = time.time()  # the bus's timestamps are wall-clock times
        counter = data[0] if data else 0
        with self._lock:
            if self._last is not None and timestamp > self._last:
                self._intervals.append(timestamp - self._last)
            self._last = timestamp
            period = statistics.median(self._intervals) if self._intervals else None
            late = period is not None and answered - timestamp > LATE_FRACTION * period
            for k, node in enumerate(self.nodes):
                if node.state != OPERATIONAL:
                    continue
                if late:
                    self.late += 1
                else:
                    self.writer.write(timestamp, counter, node.node_id, self.source.force_N[k])

    def close(self) -> None:
        with self._lock:
            self.writer.close()


@contextlib.contextmanager
def truth_log(path: str | os.PathLike[str], network: canopen.Network, source: TruthSource,
              nodes: Sequence[PatchNode]) -> Iterator[TruthLog]:
    """Write the truth while inside; the file is synced and closed on leaving, however the
    block ends (``skin`` turns SIGTERM and SIGHUP into Ctrl-C's KeyboardInterrupt)."""
    log = TruthLog(path, source, nodes)
    network.subscribe(SYNC_COB_ID, log.on_sync)
    try:
        yield log
    finally:
        network.unsubscribe(SYNC_COB_ID, log.on_sync)
        log.close()
