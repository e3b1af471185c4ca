"""hysteresis: a play (backlash) operator on q = R/R0 - 1, stateful over time."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from sim.params import positive

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class HysteresisParams:
    width: float = 0.005

    RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "width": (0.0, 1.0)}

    def check(self, where: str) -> None:
        positive(self.width, f"{where}.width")


class Hysteresis:
    """y_k = clip(y_{k-1}, x_k - w/2, x_k + w/2), starting from y = 0 at rest.

    On a loading-unloading cycle the two branches are ``width`` apart in q.
    """

    def __init__(self, p: HysteresisParams, shape: tuple[int, ...]) -> None:
        self.half = 0.5 * p.width
        self.state = np.zeros(shape)

    def apply(self, q: F64) -> F64:
        """q (n, ...) -> the played output, looping over time, vectorised over the rest."""
        out = np.empty_like(q)
        y = self.state
        for k in range(q.shape[0]):
            y = np.clip(y, q[k] - self.half, q[k] + self.half)
            out[k] = y
        self.state = y.copy()
        return out
