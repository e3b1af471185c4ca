"""Signal sources: where patch nodes get their resistances from.

Anything with ``node_ids``, ``pillars`` and ``read() -> (patches, 9, P)`` ohms is a
source. :class:`SimulatorSource` adapts ``sim.Simulator`` (one time step per read);
:class:`ArraySource` replays recorded resistances in a loop.
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
    """One ``Simulator.step()`` per read: the patches report what the simulator produced."""

    def __init__(self, simulator: Simulator) -> None:
        self.simulator = simulator
        self.node_ids = tuple(int(n) for n in simulator.node_ids)
        self.pillars = int(simulator.pillars)

    def read(self) -> NDArray[np.float64]:
        return np.asarray(self.simulator.step().resistance_ohm[0], dtype=np.float64)


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
