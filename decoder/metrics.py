"""Accuracy metrics: the paper's AveRelErr (Eq. 22) and the ones that do not explode near zero.

Eq. 22 averages |(F' - F)/F| over every tested force component, so a few
forces near 0 N dominate it; the floored variant keeps only |F| >= 5 % of full
scale. Components compared are Fz in z-only mode (the paper's) and all three
in 3-axis mode. Taxels a decoder masked invalid are excluded and counted: every report
says the share of the taxels its figures cover (``ErrorReport.covered_share``), and a
figure over nothing (every taxel masked, or no force at or above the floor) is NaN, never
0 %.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skin.constants import DEFAULT_CONSTANTS, SensorConstants

EDGE_TAXELS = (0, 1, 2, 3, 5, 6, 7, 8)
CENTRE_TAXEL = 4
FLOOR_FRACTION = 0.05


@dataclass(frozen=True)
class ErrorReport:
    """Accuracy of one decoder on one test set (percentages are of full scale or relative)."""

    ave_rel_err_pct: float
    ave_rel_err_floored_pct: float
    rmse_N: float
    rmse_pct_fs: float
    max_abs_err_N: float
    max_rel_err_floored_pct: float
    rmse_edge_N: float
    rmse_centre_N: float
    compared: int
    masked: int
    floored: int = 0  # components compared in the floored figures
    taxels: int = 0  # taxels decoded, masked or not

    @property
    def covered(self) -> int:
        """Taxels the figures cover: decoded and not masked."""
        return self.taxels - self.masked

    @property
    def covered_share(self) -> float:
        """The share of the taxels the figures cover, 0..1 (0 with no taxel)."""
        return self.covered / self.taxels if self.taxels else 0.0

    def to_dict(self) -> dict[str, float | int]:
        return asdict(self) | {"covered": self.covered, "covered_share": self.covered_share}


def _components(force: NDArray[np.float64], mode: str) -> NDArray[np.float64]:
    return force[..., 2:3] if mode == "z" else force


def _rmse(err: NDArray[np.float64]) -> float:
    return float(np.sqrt(np.mean(err * err))) if err.size else float("nan")


def ave_rel_err(true: ArrayLike, pred: ArrayLike) -> float:
    """Eq. 22 in %: mean |(F' - F) / F| over components with F != 0."""
    t, p = np.asarray(true, np.float64).ravel(), np.asarray(pred, np.float64).ravel()
    keep = t != 0.0
    if not keep.any():
        return float("nan")
    return float(100.0 * np.mean(np.abs((p[keep] - t[keep]) / t[keep])))


def evaluate(
    true_N: ArrayLike, pred_N: ArrayLike, valid: ArrayLike | None = None, *, mode: str = "z",
    constants: SensorConstants = DEFAULT_CONSTANTS,
) -> ErrorReport:
    """Compare forces (samples, [patches,] 9, 3); ``mode`` "z" compares Fz only, "xyz" all."""
    t = np.asarray(true_N, np.float64).reshape(-1, 9, 3)
    p = np.asarray(pred_N, np.float64).reshape(-1, 9, 3)
    ok = (np.ones(t.shape[:2], bool) if valid is None
          else np.asarray(valid, bool).reshape(t.shape[:2]))
    t, p = _components(t, mode), _components(p, mode)
    mask = np.broadcast_to(ok[..., None], t.shape)
    tv, pv = t[mask], p[mask]
    err = pv - tv
    fs = constants.full_scale_force_N
    floored = np.abs(tv) >= FLOOR_FRACTION * fs
    # no component at or above the floor: no floored figure at all (NaN), never 0 %
    rel_floor = np.abs(err[floored] / tv[floored]) if floored.any() else np.full(1, np.nan)
    edge = mask.copy()
    edge[:, CENTRE_TAXEL] = False
    centre = mask.copy()
    centre[:, list(EDGE_TAXELS)] = False
    return ErrorReport(
        ave_rel_err_pct=ave_rel_err(tv, pv),
        ave_rel_err_floored_pct=float(100.0 * np.mean(rel_floor)),
        rmse_N=_rmse(err),
        rmse_pct_fs=100.0 * _rmse(err) / fs,
        max_abs_err_N=float(np.max(np.abs(err))) if err.size else float("nan"),
        max_rel_err_floored_pct=float(100.0 * np.max(rel_floor)),
        rmse_edge_N=_rmse((p - t)[edge]),
        rmse_centre_N=_rmse((p - t)[centre]),
        compared=int(tv.size),
        masked=int(np.count_nonzero(~ok)),
        floored=int(np.count_nonzero(floored)),
        taxels=int(ok.size),
    )


AXES = ("x", "y", "z")


def rmse_per_axis(
    true_N: ArrayLike, pred_N: ArrayLike, valid: ArrayLike | None = None, *, mode: str = "z",
) -> dict[str, float]:
    """RMSE in N of each compared component (Fz only in z-only mode) over the valid taxels;
    NaN for a component when no taxel is valid."""
    t = np.asarray(true_N, np.float64).reshape(-1, 9, 3)
    p = np.asarray(pred_N, np.float64).reshape(-1, 9, 3)
    ok = (np.ones(t.shape[:2], bool) if valid is None
          else np.asarray(valid, bool).reshape(t.shape[:2]))
    err = (p - t)[ok]
    axes = (2,) if mode == "z" else (0, 1, 2)
    return {AXES[a]: _rmse(err[:, a]) for a in axes}
