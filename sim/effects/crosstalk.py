"""elastic_crosstalk: the rubber between taxels spreads each force to its neighbours."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from sim.params import non_negative

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class CrosstalkParams:
    coupling: float = 0.05
    diagonal_coupling: float = 0.02

    RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "coupling": (0.0, 1.0), "diagonal_coupling": (0.0, 1.0)}

    def check(self, where: str) -> None:
        non_negative(self.coupling, f"{where}.coupling")
        non_negative(self.diagonal_coupling, f"{where}.diagonal_coupling")


def crosstalk_matrix(coupling: float, diagonal_coupling: float) -> F64:
    """M (9, 9) with F_eff = M @ F per component: I + c·(4-neighbours) + d·(diagonals).

    Edge and corner taxels have fewer neighbours, so they gather less force.
    """
    row, col = np.divmod(np.arange(9), 3)
    dr = np.abs(row[:, None] - row[None, :])
    dc = np.abs(col[:, None] - col[None, :])
    side = (dr + dc == 1).astype(np.float64)
    diagonal = ((dr == 1) & (dc == 1)).astype(np.float64)
    matrix: F64 = np.eye(9) + coupling * side + diagonal_coupling * diagonal
    return matrix


def apply_crosstalk(matrix: F64, force_N: F64) -> F64:
    """Effective force (..., 9, 3) = M @ F, per component."""
    out: F64 = matrix @ force_N
    return out
