"""Signal sources: where patch nodes get their resistances from.

Anything with ``node_ids``, ``pillars`` and ``read() -> (patches, 9, P)`` ohms is a
source. :class:`SimulatorSource` adapts ``sim.Simulator`` (one time step per read,
simulated ``ahead`` steps at a time); :class:`ArraySource` replays recorded resistances in a
loop.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:
    from sim import Simulator


class ResistanceSource(Protocol):
    node_ids: tuple[int, ...]
    pillars: int

    def read(self) -> NDArray[np.float64]:
        """The next sample: ``(patches, 9, P)`` resistances in ohm."""
        ...


class SimulatorSource:
    """One simulator time step per read: the patches report what the simulator produced.

    ``ahead``: steps simulated at once, then read one by one (``Simulator.run(ahead)`` is
    vectorised over time: 10 steps of 16 loaded 3-axis patches cost about twice one step).
    """

    def __init__(self, simulator: Simulator, *, ahead: int = 1) -> None:
        if ahead < 1:
            raise ValueError(f"ahead must be at least 1 step, got {ahead}")
        self.simulator = simulator
        self.node_ids = tuple(int(n) for n in simulator.node_ids)
        self.pillars = int(simulator.pillars)
        self.ahead = ahead
        self._block: NDArray[np.float64] = np.empty((0, len(self.node_ids), 9, self.pillars))
        self._next = 0

    def read(self) -> NDArray[np.float64]:
        if self._next == len(self._block):
            self._block = np.asarray(self.simulator.run(self.ahead).resistance_ohm,
                                     dtype=np.float64)
            self._next = 0
        sample: NDArray[np.float64] = self._block[self._next]
        self._next += 1
        return sample


class ArraySource:
    """Replays ``(samples, patches, 9, P)`` resistances, starting over at the end."""

    def __init__(self, resistance_ohm: ArrayLike, node_ids: tuple[int, ...]) -> None:
        self.samples = np.asarray(resistance_ohm, dtype=np.float64)
        if self.samples.ndim != 4 or self.samples.shape[1:3] != (len(node_ids), 9):
            raise ValueError(f"expected (samples, {len(node_ids)}, 9, P), got {self.samples.shape}")
        self.node_ids = node_ids
        self.pillars = int(self.samples.shape[3])
        self.position = 0

    def read(self) -> NDArray[np.float64]:
        sample = self.samples[self.position]
        self.position = (self.position + 1) % len(self.samples)
        return np.asarray(sample, dtype=np.float64)
