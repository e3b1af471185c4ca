"""The passive-matrix pillar network of one patch and its two-point resistances.

Wiring (docs/sim.md): taxel (r, c) has upper wires A_r (electrode 2) and B_r
(electrode 7) and lower wires C_c (electrode 3) and D_c (electrode 5). Pillar z
joins A_r-C_c, pillar x joins A_r-D_c, pillar y joins B_r-C_c: 12 wires, 27
pillars, each pillar the only resistor on its wire pair.

Upper wires are numbered A0..A2, B0..B2 (0..5), lower wires C0..C2, D0..D2
(0..5). The network is bipartite, so its Laplacian is [[Du, -W], [-Wᵀ, Dl]]
with W the upper-lower conductance matrix and Dl diagonal. With upper wire B2
grounded, the reduced Laplacian's inverse follows from the 5×5 Schur
complement S = Du' - W' Dl⁻¹ W'ᵀ, so one batched 5×5 inverse per patch-sample
replaces an 11×11 one. The two-point resistance between wires a and b is
G_aa + G_bb - 2·G_ab, G the inverse of the grounded Laplacian.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

_row, _col = np.divmod(np.repeat(np.arange(9), 3), 3)
_pillar = np.tile(np.arange(3), 9)  # 0 = z, 1 = x, 2 = y; flat index = 3 * taxel + pillar
UPPER_WIRE = np.where(_pillar == 2, 3 + _row, _row)
"""Upper wire (A_r = r, B_r = 3 + r) of each of the 27 pillars, in flat order."""
LOWER_WIRE = np.where(_pillar == 1, 3 + _col, _col)
"""Lower wire (C_c = c, D_c = 3 + c) of each of the 27 pillars, in flat order."""

_SCATTER = np.zeros((27, 36))
_SCATTER[np.arange(27), 6 * UPPER_WIRE + LOWER_WIRE] = 1.0
_GROUNDED = 5  # upper wire B2


def passive_matrix_resistance(r_ohm: F64) -> F64:
    """Measured resistance (..., 9, 3) of every pillar when read through the passive matrix."""
    lead = r_ohm.shape[:-2]
    g = 1.0 / r_ohm.reshape(-1, 27)
    w = (g @ _SCATTER).reshape(-1, 6, 6)  # upper x lower conductances
    d_upper = w.sum(axis=2)
    d_lower = w.sum(axis=1)
    wr = w[:, :_GROUNDED, :]
    v = wr / d_lower[:, None, :]
    schur = -np.matmul(v, wr.transpose(0, 2, 1))
    diag = np.arange(_GROUNDED)
    schur[:, diag, diag] += d_upper[:, :_GROUNDED]
    g_upper = np.linalg.inv(schur)
    h = np.matmul(g_upper, v)  # G between upper (kept) and lower wires
    n = g.shape[0]
    self_upper = np.zeros((n, 6))
    self_upper[:, :_GROUNDED] = g_upper[:, diag, diag]
    self_lower = 1.0 / d_lower + np.einsum("nab,nab->nb", v, h)
    cross = np.zeros((n, 6, 6))
    cross[:, :_GROUNDED, :] = h
    out = (
        self_upper[:, UPPER_WIRE] + self_lower[:, LOWER_WIRE]
        - 2.0 * cross[:, UPPER_WIRE, LOWER_WIRE]
    )
    result: F64 = out.reshape(*lead, 9, 3)
    return result
