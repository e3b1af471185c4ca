"""Contact geometry on one patch: taxel centres and a Hertzian sphere."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from skin.contact import taxel_xy

F64 = NDArray[np.float64]


def sphere_fz(
    cx: F64, cy: F64, depth_m: F64, *, radius_m: float, depth_max_m: float, fz_max_N: float,
    pitch_m: float,
) -> F64:
    """Normal force per taxel, shape (*cx.shape, 9), of a sphere pressed to ``depth_m`` at (cx, cy).

    Each taxel is a Hertzian contact of its own: the local indentation is the
    depth minus the sphere's sag r^2/(2R) at the taxel centre, and the force
    grows as indentation^1.5, reaching ``fz_max_N`` under the centre at
    ``depth_max_m``.
    """
    x, y = taxel_xy(pitch_m).T
    r2 = (cx[..., None] - x) ** 2 + (cy[..., None] - y) ** 2
    indent = np.maximum(depth_m[..., None] - r2 / (2.0 * radius_m), 0.0) / depth_max_m
    fz: F64 = fz_max_N * indent * np.sqrt(indent)
    return fz
