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

What is added is the residual less its own uncertainty (a soft threshold): each
output's residual is shrunk towards zero by ``RESIDUAL_Z`` times its standard
error, and is zero where it is smaller than that. The standard error is measured
in training: a second network of the same size, trained from another start on
another split, gives another residual; half the mean square difference of the
two over the training rows is the variance of one network's residual. A network
trained on noisy readings also fits part of the noise; that part differs from
one network to the next, so it lies within the threshold and is removed, while
what the data do support (the shear of a pure press is zero) is far above it and
is kept. Without the threshold, hybrid trained on ``paper-noisy`` in 3-axis mode
decoded the noise-free ``paper`` 4x-7x worse than its physics part (0.19 %
floored against 0.03 %): on a reading without noise, the fitted noise was all
that its residual added. The second network doubles the training time; decoding
pays one clip per sample.

And the residual of each output (a taxel's force component) is used at all only
if it earns its place: if on the validation rows the thresholded residual removes
at least ``RESIDUAL_GAIN`` of the physics part's mean square error for that
output. On ``paper-noisy`` deconv's Fz is already at the noise floor, and a
network would only learn the noise; in 3-axis mode the network does learn that
the shear of a pure press is zero, and keeps that.
The physics part was chosen so that this fallback is worth having: deconv's
crosstalk inverse is linear and transfers between load distributions, where
the plain analytic inverse is off by the whole crosstalk (tens of percent).

Taxels are flagged as ``deconv`` flags them: EXTRAPOLATED when the analytic
force or the physics force leaves the training box (widened as deconv's).
"""

from __future__ import annotations

from typing import Any, Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from decoder.box import Box, expect_array
from decoder.domain import Domain, Ellipsoid, check_margin, domain_reasons, per_taxel
from decoder.lm import LMOptions
from decoder.patchcheck import block_margin
from decoder.physics import features, taxel_reasons, to_force
from decoder.protocol import (
    F64,
    Progress,
)
from decoder.regressor import FoldedMLP, MLPDecoderBase, fit_mlp, sample_rows
from decoder.unmix import apply_unmix, fit_unmix, unmix_rows
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.errors import DecodeError, ModelFileError

RESIDUAL_GAIN = 0.1
RESIDUAL_FLOOR_N2 = 1e-12
"""Below this held-out MSE (1 µN RMS) the physics part is exact and there is nothing to learn."""
RESIDUAL_Z = 2.0
"""The residual counts only by what exceeds this many standard errors (the 95 % level)."""


def soft_threshold(residual: F64, threshold: F64) -> F64:
    """Each value moved towards 0 by ``threshold`` (per output), and 0 within it."""
    shrunk: F64 = residual - np.clip(residual, -threshold, threshold)
    return shrunk


class HybridDecoder(MLPDecoderBase):
    """deconv's physics plus an MLP-learned residual that is used only inside its domain."""

    name = "hybrid"
    _params = ("constants", "r0_ohm", "hidden", "goal_mse", "goal_units", "max_epochs",
               "val_fraction", "seed", "alpha", "range_margin")
    _state = (*MLPDecoderBase._state, "unmix_", "domain_", "residual_domain_", "use_residual_",
              "residual_threshold_")
    unmix_: F64
    use_residual_: NDArray[np.bool_]
    residual_threshold_: F64
    domain_: Domain | None
    residual_domain_: Domain | None

    def __init__(self, *, constants: SensorConstants = DEFAULT_CONSTANTS,
                 r0_ohm: ArrayLike | None = None, hidden: int | str = 12,
                 goal_mse: float = 1e-4, goal_units: str = "N", max_epochs: int = 300,
                 val_fraction: float = 0.15, seed: int = 0, alpha: float = 1e-2,
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
        data = self.training_samples(resistance_ohm, force_N)
        effective, force, pillars = data.effective_N, data.force_N, data.pillars
        for stale in ("use_residual_", "residual_threshold_"):  # of an earlier fit
            self.__dict__.pop(stale, None)
        self.unmix_info_ = fit_unmix(*unmix_rows(effective, force, pillars), self.alpha)
        self.unmix_ = self.unmix_info_.matrix
        physics = features(apply_unmix(self.unmix_, effective), pillars)
        analytic = features(effective, pillars)
        self.domain_ = Domain(Box.fit(analytic, max(self.range_margin, block_margin(analytic))),
                              Box.fit(physics, max(self.range_margin, block_margin(physics))))
        wanted = features(force, pillars) - physics
        val = self._fit_scaled(physics, wanted, pillars, progress)
        residual = self._net(physics)
        self.residual_domain_ = Domain(Box.fit(physics, self.range_margin),
                                       Box.fit(residual, self.range_margin),
                                       Ellipsoid.fit(physics))
        self.residual_threshold_ = RESIDUAL_Z * self._standard_error(physics, wanted, residual)
        shrunk = soft_threshold(residual, self.residual_threshold_)
        rows = val if val.size else np.arange(physics.shape[0])
        self.val_mse_physics_ = np.mean(wanted[rows] ** 2, axis=0)
        self.val_mse_hybrid_ = np.mean((wanted[rows] - shrunk[rows]) ** 2, axis=0)
        self.use_residual_ = ((self.val_mse_hybrid_ < (1.0 - RESIDUAL_GAIN) * self.val_mse_physics_)
                              & (self.val_mse_physics_ > RESIDUAL_FLOOR_N2))
        self._prepare()
        return self

    def _standard_error(self, physics: F64, wanted: F64, residual: F64) -> F64:
        """Per output, the residual's standard error from training alone: a second network
        of the same size, from another start and split, and half the mean square difference
        of the two residuals over the training rows."""
        options = LMOptions(goal_mse=self.goal_mse, max_epochs=self.max_epochs)
        second = fit_mlp(physics, wanted, hidden=self.hidden_, options=options,
                         val_fraction=self.val_fraction, seed=self.seed + 1,
                         goal_units=self.goal_units)
        other = FoldedMLP(self._layout(), second.state)(physics)
        spread: F64 = np.sqrt(0.5 * np.mean((residual - other) ** 2, axis=0))
        return spread

    def meta(self) -> dict[str, Any]:
        meta = super().meta()
        if "unmix_info_" in self.__dict__:
            meta["crosstalk"] = self.unmix_info_.to_meta()
        if "val_mse_physics_" in self.__dict__:
            meta["residual"] = {"used": self.use_residual_,
                                "threshold_N": self.residual_threshold_,
                                "threshold_standard_errors": RESIDUAL_Z,
                                "val_mse_physics_N2": self.val_mse_physics_,
                                "val_mse_with_residual_N2": self.val_mse_hybrid_,
                                "required_gain": RESIDUAL_GAIN}
        return meta

    @classmethod
    def _upgrade(cls, params: dict[str, Any], state: dict[str, Any], version: int) -> None:
        # Version 1: analytic forces in, residual over them, features clamped to their range.
        # Versions 1 and 2: the residual added as it is (no threshold).
        super()._upgrade(params, state, version)
        params.setdefault("alpha", 1e-3)
        params.setdefault("range_margin", 0.1)
        state.setdefault("unmix_", np.eye(9))
        state.setdefault("domain_", None)
        state.setdefault("residual_domain_", None)
        pillars = state.get("pillars_")
        if pillars in (1, 3) and not isinstance(pillars, bool):
            state.setdefault("use_residual_", np.ones(9 * pillars, dtype=bool))
            state.setdefault("residual_threshold_", np.zeros(9 * pillars))

    def _check_state(self) -> None:
        super()._check_state()
        expect_array(self.unmix_, "state.unmix_", (9, 9))
        layout = self._layout()
        for key in ("domain_", "residual_domain_"):
            value = getattr(self, key)
            if value is not None:
                setattr(self, key, Domain.from_state(value, f"state.{key}", layout.n_in,
                                                     layout.n_out))
        used = self.use_residual_
        if not (isinstance(used, np.ndarray) and used.dtype == bool
                and used.shape == (layout.n_out,)):
            got = used.shape if isinstance(used, np.ndarray) else type(used).__name__
            raise ModelFileError(f"state.use_residual_: expected bool array of shape "
                                 f"({layout.n_out},), got {got}")
        threshold = expect_array(self.residual_threshold_, "state.residual_threshold_",
                                 (layout.n_out,))
        if np.any(threshold < 0):
            raise ModelFileError("state.residual_threshold_: must be >= 0")
        density = None if self.residual_domain_ is None else self.residual_domain_.density
        if self.residual_domain_ is not None and density is None:
            raise ModelFileError("state.residual_domain_: missing 'density'")
        self._prepare()

    def _corrected(self, physics: F64, checked: bool = False) -> F64:
        """Physics rows ((O,) or (n, O)) plus the residual, thresholded, wherever it is in its
        domain. ``checked``: the physics rows are known to be inside the residual's box."""
        if not self._any_residual:
            return physics
        domain = self.residual_domain_
        if domain is None:
            residual = self._net(np.minimum(np.maximum(physics, self.x_lo_), self.x_hi_))
        else:
            residual = self._net(physics)
            assert domain.density is not None
            if not ((checked or domain.inputs.all_inside(physics))
                    and domain.density.inside(physics).all()
                    and domain.outputs.all_inside(residual)):
                use = (domain.outputs.inside(residual)
                       & domain.inputs.inside(physics).all(axis=-1, keepdims=True)
                       & domain.density.inside(physics)[..., None])
                residual = np.where(use, residual, 0.0)
        residual -= np.clip(residual, -self._threshold, self._threshold)  # soft_threshold in place
        out: F64 = physics + residual
        return out

    def _prepare(self) -> None:
        super()._prepare()
        used = self.__dict__.get("use_residual_")
        threshold = self.__dict__.get("residual_threshold_")
        self._any_residual = bool(np.any(used))
        if isinstance(used, np.ndarray) and isinstance(threshold, np.ndarray):
            # An output whose residual is not used has an infinite threshold: it adds 0 N.
            self._threshold = np.where(used, threshold, np.inf)
        domain, residual = self.__dict__.get("domain_"), self.__dict__.get("residual_domain_")
        self._same_box = (isinstance(domain, Domain) and isinstance(residual, Domain)
                          and np.array_equal(domain.outputs.lo, residual.inputs.lo)
                          and np.array_equal(domain.outputs.hi, residual.inputs.hi))

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
        return to_force(self._corrected(physics, checked=self._same_box), self.pillars_)

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
