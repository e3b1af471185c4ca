"""The ``lm-mlp`` decoder: the paper's network, resistances in, forces out.

z-only: 9 resistances -> 9 normal forces; 3-axis: 27 -> 27 (Fx, Fy, Fz per taxel).
``hidden`` is a number of nodes or ``"auto"`` (the paper's Eq. 21 and pruning,
:mod:`decoder.hidden`); the goal MSE is in newtons unless ``goal_units="scaled"``.

The network knows where it was trained (:mod:`decoder.domain`,
:mod:`decoder.patchcheck`), and a taxel is EXTRAPOLATED when:

- one of its readings is outside the training readings' box (its reading is then
  clamped to the box so that the other taxels still decode);
- its force is outside the box of the training forces and of what the network
  answered on the training readings;
- the patch's physics reading (the exact inverse and the crosstalk inverse fitted
  on the same data, as ``deconv``), its 9 or 27 forces together, is a pattern the
  training set did not show (every taxel of the sample);
- the network departs from that physics reading more than it did on its validation
  rows: the patch's departures together (every taxel of the sample), or the taxel's
  own relative to its force. This catches what the input checks cannot: a pattern
  inside the spread of the training readings on which the network is nevertheless
  wrong. Where held-out blocks of the training data show that its rows are a few
  long episodes (a grasp's squeeze cycles), the validation rows cannot calibrate
  this check and it is not made.

The last two are made only when every taxel of the sample has a physics reading,
and are calibrated on held-out rows of the training data to flag few taxels of the
training scene (about 1 %). Model files of version 3 and before keep their checks
(an ellipsoid of the readings, bands on the departure per component and per taxel).

A taxel with a faulty pillar, or one the physics cannot decode, keeps its
electrical reason or OUT_OF_RANGE; its readings are replaced by the middle of the
training range so the other taxels still decode.
"""

from __future__ import annotations

from typing import Any, Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from decoder.box import expect_array
from decoder.domain import Domain, check_margin, domain_reasons, per_taxel
from decoder.metrics import FLOOR_FRACTION
from decoder.patchcheck import fit_boxes, fit_patch_checks
from decoder.physics import features, taxel_reasons, to_force
from decoder.protocol import (
    F64,
    Progress,
    fold_resistance,
)
from decoder.regressor import MLPDecoderBase, sample_rows
from decoder.unmix import apply_unmix, fit_unmix, unmix_rows
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.constants import TAXELS_PER_PATCH as T
from skin.errors import ModelFileError

UNMIX_ALPHA = 1e-2
"""Tikhonov weight of the physics reference's crosstalk inverse (deconv's default)."""
JUDGED = ("band", "taxel_band", "pattern", "departure")
"""The domain's checks that judge the physics reading or the departure from it."""


class LMMLPDecoder(MLPDecoderBase):
    """Resistances -> one tanh hidden layer -> forces, trained by Levenberg-Marquardt."""

    name = "lm-mlp"
    _params = ("constants", "r0_ohm", "hidden", "goal_mse", "goal_units", "max_epochs",
               "val_fraction", "seed", "range_margin")
    _state = (*MLPDecoderBase._state, "unmix_", "domain_")
    unmix_: F64 | None
    domain_: Domain

    def __init__(self, *, hidden: int | str = 10, goal_mse: float = 1e-4,
                 goal_units: str = "N", max_epochs: int = 1000, val_fraction: float = 0.15,
                 seed: int = 0, range_margin: float = 0.1,
                 constants: SensorConstants = DEFAULT_CONSTANTS,
                 r0_ohm: ArrayLike | None = None) -> None:
        super().__init__(constants=constants, r0_ohm=r0_ohm, hidden=hidden, goal_mse=goal_mse,
                         goal_units=goal_units, max_epochs=max_epochs,
                         val_fraction=val_fraction, seed=seed)
        self.range_margin = check_margin(range_margin)

    def fit(self, resistance_ohm: ArrayLike, force_N: ArrayLike, *,
            progress: Progress | None = None) -> Self:
        data = self.training_samples(resistance_ohm, force_N)
        pillars = data.pillars
        x = data.resistance_ohm.reshape(-1, T * pillars)
        y = features(data.force_N, pillars)
        val = self._fit_scaled(x, y, pillars, progress)
        self.unmix_ = fit_unmix(*unmix_rows(data.effective_N, data.force_N, pillars),
                                UNMIX_ALPHA).matrix
        physics = features(apply_unmix(self.unmix_, data.effective_N), pillars)
        predicted = self._net(x)
        checks = fit_patch_checks(predicted - physics, physics, val,
                                  FLOOR_FRACTION * self.constants.full_scale_force_N)
        inputs, outputs, checks = fit_boxes(x, y, predicted, self.range_margin, checks)
        self.domain_ = Domain(inputs, outputs, pattern=checks.pattern,
                              departure=checks.departure)
        self.patch_checks_ = checks
        self._prepare()
        return self

    def meta(self) -> dict[str, Any]:
        meta = super().meta()
        checks = self.__dict__.get("patch_checks_")
        if checks is not None and "training" in meta:
            meta["domain"] = checks.to_meta()
        return meta

    def predict(self, resistance_ohm: ArrayLike) -> F64:
        """The network's forces (samples, [patches,] 9, 3) on every taxel, with no domain check
        and no masking: what the paper's protocol scores (Eq. 22 over every test component). A
        robot should use :meth:`decode`, which says where the network is not to be trusted."""
        r, lead = fold_resistance(resistance_ohm)
        self._check_decodable(r.shape[2])
        force: F64 = to_force(self._net(r.reshape(r.shape[0], -1)), self.pillars_)
        return force.reshape(*lead, T, 3)

    @classmethod
    def _upgrade(cls, params: dict[str, Any], state: dict[str, Any], version: int) -> None:
        super()._upgrade(params, state, version)
        margin = params.setdefault("range_margin", 0.1)
        state.setdefault("unmix_", None)
        if "domain_" not in state and {"x_lo_", "x_hi_", "y_lo_", "y_hi_"} <= set(state):
            x_lo, x_hi, y_lo, y_hi = (state[k] for k in ("x_lo_", "x_hi_", "y_lo_", "y_hi_"))
            if all(isinstance(a, np.ndarray) for a in (x_lo, x_hi, y_lo, y_hi)):
                # Version 1 masked readings beyond each one's own range widened by the
                # margin; keep exactly that, and check the forces against their range too.
                widen_x, widen_y = margin * (x_hi - x_lo), margin * np.max(y_hi - y_lo)
                state["domain_"] = {"inputs": {"lo": x_lo - widen_x, "hi": x_hi + widen_x},
                                    "outputs": {"lo": y_lo - widen_y, "hi": y_hi + widen_y}}

    def _check_state(self) -> None:
        super()._check_state()
        layout = self._layout()
        if self.unmix_ is not None:
            expect_array(self.unmix_, "state.unmix_", (9, 9))
        self.domain_ = Domain.from_state(self.domain_, "state.domain_", layout.n_in,
                                         layout.n_out)
        for key in JUDGED:
            if getattr(self.domain_, key) is not None and self.unmix_ is None:
                raise ModelFileError(f"state.domain_.{key}: needs state.unmix_")
        self._prepare()

    def _prepare(self) -> None:
        super()._prepare()
        self._mid = 0.5 * (self.x_lo_ + self.x_hi_)
        domain = self.__dict__.get("domain_")
        self._judged = isinstance(domain, Domain) and any(
            getattr(domain, key) is not None for key in JUDGED)

    def _physics(self, effective: F64) -> F64:
        """Analytic forces (Fz (n, 9) or (n, 9, 3)) -> the physics reading as feature rows."""
        assert self.unmix_ is not None
        return sample_rows(features(apply_unmix(self.unmix_, effective), self.pillars_))

    def _decode_fast(self, r: F64) -> F64 | None:
        x = sample_rows(r)
        domain = self.domain_
        if not domain.inputs.all_inside(x):
            return None
        if domain.density is not None and not domain.density.inside(x).all():
            return None
        y = self._net(x)
        if not domain.outputs.all_inside(y):
            return None
        if self._judged:
            effective = self.inverse(self.pillars_).fast(r)
            if effective is None or not self._physics_inside(y, effective):
                return None
        return to_force(y, self.pillars_)

    def _physics_inside(self, y: F64, effective: F64) -> bool:
        """Whether the physics reading of ``effective`` and the network's rows ``y`` are inside
        every check that judges them, on every taxel (the fast path's check)."""
        domain = self.domain_
        physics = self._physics(effective)
        departure = y - physics
        return ((domain.band is None or domain.band.all_inside(departure))
                and (domain.taxel_band is None or domain.taxel_band.all_inside(departure))
                and (domain.pattern is None or bool(domain.pattern.inside(physics).all()))
                and (domain.departure is None
                     or domain.departure.all_inside(departure, physics)))

    def _decode_full(self, r: F64) -> tuple[F64, NDArray[np.uint8]]:
        n, pillars = r.shape[0], self.pillars_
        x = r.reshape(n, T * pillars)
        domain = self.domain_
        effective, ok = self.inverse(pillars).full(r)
        reason = taxel_reasons(r, ok, self.constants)
        faulty = np.repeat(reason != 0, pillars, axis=1)
        domain_reasons(reason, per_taxel(~domain.inputs.inside(x)))
        x = domain.inputs.clamp(np.where(faulty, self._mid, x))
        if domain.density is not None:
            domain_reasons(reason, ~domain.density.inside(x)[:, None])
        y = self._net(sample_rows(x)).reshape(n, -1)  # one sample as a vector, as on the fast path
        domain_reasons(reason, per_taxel(~domain.outputs.inside(y)))
        if self._judged and self.unmix_ is not None:
            whole = np.asarray(ok.all(axis=1))[:, None]
            physics = features(apply_unmix(self.unmix_, effective), pillars)
            departure = y - physics
            if domain.band is not None:
                domain_reasons(reason, per_taxel(~domain.band.inside(departure)) & whole)
            if domain.taxel_band is not None:
                domain_reasons(reason, ~domain.taxel_band.inside(departure) & whole)
            if domain.pattern is not None:
                domain_reasons(reason, ~domain.pattern.inside(physics)[:, None] & whole)
            if domain.departure is not None:
                domain_reasons(reason, ~domain.departure.inside(departure, physics) & whole)
        return to_force(y, pillars), reason
