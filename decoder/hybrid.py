"""The ``hybrid`` decoder: physics first, then a small LM-trained MLP that learns the residual.

The physics part is ``deconv``'s: the exact inverse, then the crosstalk inverse
calibrated on the training data (:func:`decoder.unmix.fit_unmix`). Its forces
(9 Fz in z-only mode, 27 components in 3-axis mode) are the network's features,
and the network learns true minus physics (what the exact model and a linear
crosstalk do not explain). Its output is added back only where it is inside the
residual's training domain:

- the sample's features inside their training box and ellipsoid
  (:mod:`decoder.domain`), else no residual for the whole sample;
- each residual inside the range of the training residuals, else none for that
  force component.

Outside, hybrid is its physics part: it falls back instead of adding a guess.
The physics part was chosen so that this fallback is worth having: deconv's
crosstalk inverse is linear and transfers between load distributions, where
the plain analytic inverse is off by the whole crosstalk (tens of percent).

Taxels are flagged as ``deconv`` flags them: EXTRAPOLATED when the analytic
force or the physics force leaves the training box.
"""

from __future__ import annotations

from typing import Any, Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from decoder.deconv import check_margin, domain_reasons, features
from decoder.domain import Box, Domain, Ellipsoid, per_taxel
from decoder.lmmlp import apply_unmix, targets, unmix_rows
from decoder.physics import solve, taxel_reasons, to_force
from decoder.protocol import (
    F64,
    Progress,
    expect_array,
    fold_force,
    fold_resistance,
)
from decoder.regressor import MLPDecoderBase, sample_rows
from decoder.unmix import fit_unmix
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.errors import DecodeError, ModelFileError


class HybridDecoder(MLPDecoderBase):
    """deconv's physics plus an MLP-learned residual that is used only inside its domain."""

    name = "hybrid"
    _params = ("constants", "r0_ohm", "hidden", "goal_mse", "goal_units", "max_epochs",
               "val_fraction", "seed", "alpha", "range_margin")
    _state = (*MLPDecoderBase._state, "unmix_", "domain_", "residual_domain_")
    unmix_: F64
    domain_: Domain | None
    residual_domain_: Domain | None

    def __init__(self, *, constants: SensorConstants = DEFAULT_CONSTANTS,
                 r0_ohm: ArrayLike | None = None, hidden: int | str = 12,
                 goal_mse: float = 1e-4, goal_units: str = "N", max_epochs: int = 300,
                 val_fraction: float = 0.15, seed: int = 0, alpha: float = 1e-3,
                 range_margin: float = 0.1) -> None:
        super().__init__(constants=constants, r0_ohm=r0_ohm, hidden=hidden, goal_mse=goal_mse,
                         goal_units=goal_units, max_epochs=max_epochs,
                         val_fraction=val_fraction, seed=seed)
        if not (isinstance(alpha, float | int) and 0.0 < alpha < 1e6):
            raise DecodeError(f"alpha must be in (0, 1e6), got {alpha!r}")
        self.alpha = float(alpha)
        self.range_margin = check_margin(range_margin)

    def fit(self, resistance_ohm: ArrayLike, force_N: ArrayLike, *,
            progress: Progress | None = None) -> Self:
        r, _ = fold_resistance(resistance_ohm)
        force = fold_force(force_N, r.shape[0])
        pillars = r.shape[-1]
        effective, reason = solve(self.inverse(pillars), r, self.constants)
        keep = np.all(reason == 0, axis=1)
        if not np.any(keep):
            raise DecodeError("no training sample has all nine taxels valid")
        effective, force = effective[keep], force[keep]
        self.unmix_ = fit_unmix(*unmix_rows(effective, force, pillars), self.alpha)
        physics = features(apply_unmix(self.unmix_, effective), pillars)
        self.domain_ = Domain(Box.fit(features(effective, pillars), self.range_margin),
                              Box.fit(physics, self.range_margin))
        self._fit_scaled(physics, targets(force, pillars) - physics, pillars, progress)
        residual = self._net(physics)
        self.residual_domain_ = Domain(Box.fit(physics, self.range_margin),
                                       Box.fit(residual, self.range_margin),
                                       Ellipsoid.fit(physics))
        return self

    @classmethod
    def _upgrade(cls, params: dict[str, Any], state: dict[str, Any], version: int) -> None:
        # Version 1: analytic forces in, residual over them, features clamped to their range.
        super()._upgrade(params, state, version)
        params.setdefault("alpha", 1e-3)
        params.setdefault("range_margin", 0.1)
        state.setdefault("unmix_", np.eye(9))
        state.setdefault("domain_", None)
        state.setdefault("residual_domain_", None)

    def _state_value(self, key: str) -> Any:
        value = getattr(self, key)
        return value.to_state() if isinstance(value, Domain) else value

    def _check_state(self) -> None:
        super()._check_state()
        expect_array(self.unmix_, "unmix_", (9, 9))
        layout = self._layout()
        for key in ("domain_", "residual_domain_"):
            value = getattr(self, key)
            if value is not None:
                setattr(self, key, Domain.from_state(value, f"state.{key}", layout.n_in,
                                                     layout.n_out))
        density = None if self.residual_domain_ is None else self.residual_domain_.density
        if self.residual_domain_ is not None and density is None:
            raise ModelFileError("state.residual_domain_: missing 'density'")

    def _corrected(self, physics: F64) -> F64:
        """Physics rows ((O,) or (n, O)) plus the residual wherever it is in its domain."""
        domain = self.residual_domain_
        if domain is None:
            residual = self._net(np.minimum(np.maximum(physics, self.x_lo_), self.x_hi_))
        else:
            residual = self._net(physics)
            assert domain.density is not None
            use = (domain.outputs.inside(residual)
                   & domain.inputs.inside(physics).all(axis=-1, keepdims=True)
                   & domain.density.inside(physics)[..., None])
            residual = np.where(use, residual, 0.0)
        out: F64 = physics + residual
        return out

    def _physics(self, effective: F64) -> F64:
        return sample_rows(features(apply_unmix(self.unmix_, effective), self.pillars_))

    def _decode_fast(self, r: F64) -> F64 | None:
        effective = self.inverse(self.pillars_).fast(r)
        if effective is None:
            return None
        physics = self._physics(effective)
        domain = self.domain_
        if domain is not None and not (
                domain.inputs.all_inside(sample_rows(features(effective, self.pillars_)))
                and domain.outputs.all_inside(physics)):
            return None
        return to_force(self._corrected(physics), self.pillars_)

    def _decode_full(self, r: F64) -> tuple[F64, NDArray[np.uint8]]:
        effective, ok = self.inverse(self.pillars_).full(r)  # 0 N where not ok
        physics = self._physics(effective)
        reason = taxel_reasons(r, ok, self.constants)
        domain = self.domain_
        if domain is not None:
            n = r.shape[0]
            outside = ~(domain.inputs.inside(features(effective, self.pillars_))
                        & domain.outputs.inside(physics.reshape(n, -1)))
            domain_reasons(reason, per_taxel(outside))
        return to_force(self._corrected(physics), self.pillars_), reason
