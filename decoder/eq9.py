"""The ``eq9`` decoder: the paper's own reading, Eq. 9, per pillar, no training.

The paper takes each pillar's length change as the electrode's displacement
along one axis and reads one force component from one pillar:
F_i = (E·S/l_i)·√(V_i/ρ)·(√R_i − √R'_i) = E·S·(1 − √(R'_i/R_i)) (Eq. 9 with
V = S·l). Pillar z gives Fz (a press shortens it), pillar x gives Fx (a push
along +x shortens it), pillar y gives Fy (a push along +y lengthens it); the
signs are ``skin.smallstrain.PAPER_SIGNS``. It knows nothing of the tripod's
geometry or of crosstalk, so it shows what the exact model (``analytic``) and
the crosstalk inverse (``deconv``) buy over the paper's reading at about the
same speed (``skin model approx`` gives its model error alone).

1 − √(R'/R) is computed as −q / (1 + √(1 + q)) with q = R'/R − 1, so forces near
zero keep their digits. A pillar strained beyond the paper's 20 % (or the
constants' ``max_strain``) is OUT_OF_RANGE; electrical faults get their reasons.
"""

from __future__ import annotations

from typing import Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from decoder.physics import taxel_reasons
from decoder.protocol import F64, BaseDecoder, Progress, fold_resistance
from decoder.reasons import saturation_ohm
from skin.constants import TAXELS_PER_PATCH as T
from skin.smallstrain import PAPER_SIGNS

SIGNS_ZXY = np.array([PAPER_SIGNS[2], PAPER_SIGNS[0], PAPER_SIGNS[1]])
"""Sign of E·S·strain per pillar in the order read (z, x, y) -> (Fz, Fx, Fy)."""
COMPONENT = np.array([2, 0, 1])
"""Force component (Fx, Fy, Fz index) each pillar (z, x, y) gives."""


class Eq9Decoder(BaseDecoder):
    """E·S·(1 − √(R'/R0)) per pillar: the paper's small-strain reading."""

    name = "eq9"
    _limits_cache: tuple[tuple[int, object, object], tuple[F64, float, float, float]]

    def fit(self, resistance_ohm: ArrayLike, force_N: ArrayLike, *,
            progress: Progress | None = None) -> Self:
        fold_resistance(resistance_ohm)
        return self

    def _limits(self, pillars: int) -> tuple[F64, float, float, float]:
        """1/R0 (broadcastable), and the lowest and highest ratio R'/R0 and reading allowed;
        computed once per pillar count, constants and R0."""
        key = (pillars, self.constants, self.r0_ohm)
        cached = self.__dict__.get("_limits_cache")
        if cached is None or cached[0][1] is not key[1] or cached[0][2] is not key[2] \
                or cached[0][0] != pillars:
            strain = self.constants.max_strain
            limits = (1.0 / self.r0_for(pillars), (1.0 - strain) ** 2, (1.0 + strain) ** 2,
                      saturation_ohm(self.constants))
            cached = (key, limits)
            self._limits_cache = cached
        return cached[1]

    def _forces(self, ratio: F64) -> F64:
        """Ratios (n, 9, P) -> forces (n, 9, 3)."""
        strain = ratio - 1.0
        strain /= 1.0 + np.sqrt(ratio)
        strain *= self._gain[: ratio.shape[-1]]
        force = np.zeros((ratio.shape[0], T, 3))
        for pillar in range(ratio.shape[-1]):
            force[..., COMPONENT[pillar]] = strain[..., pillar]
        return force

    @property
    def _gain(self) -> F64:
        """E·S with the paper's sign, per pillar (z, x, y)."""
        gain: F64 = self.constants.axial_stiffness_N * SIGNS_ZXY
        return gain

    def _decode_fast(self, r: F64) -> F64 | None:
        if r.shape[0] == 0:
            return np.zeros((0, T, 3))
        inv_r0, lowest, highest, saturated = self._limits(r.shape[2])
        ratio = r * inv_r0
        if not (ratio.min() >= lowest and ratio.max() <= highest and r.max() < saturated):
            return None  # NaN fails the comparisons too
        return self._forces(ratio)

    def _decode_full(self, r: F64) -> tuple[F64, NDArray[np.uint8]]:
        inv_r0, lowest, highest, saturated = self._limits(r.shape[2])
        with np.errstate(invalid="ignore", over="ignore"):
            ratio = r * inv_r0
            good = np.asarray((ratio >= lowest) & (ratio <= highest) & (r < saturated))
        ok = np.asarray(good.all(axis=2))
        ratio = np.where(ok[..., None], ratio, 1.0)
        return self._forces(ratio), taxel_reasons(r, ok, self.constants)
