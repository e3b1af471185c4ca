"""The ``deconv`` decoder: the exact inverse, then a crosstalk inverse calibrated from data.

The rubber spreads force to neighbours, F_eff = M F per component. Given the
analytic forces F_eff and the true forces F of a calibration set, W ≈ M⁻¹ is
fit by :func:`decoder.unmix.fit_unmix`: a three-number kernel, then the full
9x9 matrix by least squares regularised towards the kernel's inverse, so too
little data or a near-singular crosstalk still give a stable, finite W.
Invalid taxels enter the deconvolution as 0 N; their neighbours still decode.

The training domain is the box of the calibration set's analytic forces and of
its decoded forces (:class:`decoder.domain.Box`, widened by ``range_margin``
of the largest span, or by what held-out blocks of the calibration rows need if
that is more: :func:`decoder.patchcheck.block_margin`): a taxel whose analytic
force or decoded force leaves it is EXTRAPOLATED.
"""

from __future__ import annotations

from typing import Any, Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from decoder.box import Box, expect_array
from decoder.domain import Domain, check_margin, domain_reasons, per_taxel
from decoder.patchcheck import block_margin
from decoder.physics import features, taxel_reasons, to_force
from decoder.protocol import (
    F64,
    BaseDecoder,
    Progress,
)
from decoder.unmix import apply_unmix, fit_unmix, unmix_rows
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.errors import DecodeError, ModelFileError


class DeconvDecoder(BaseDecoder):
    """Analytic per-taxel inverse followed by a calibrated 9x9 crosstalk inverse."""

    name = "deconv"
    _params = ("constants", "r0_ohm", "alpha", "range_margin")
    _state = ("pillars_", "unmix_", "domain_")
    pillars_: int
    unmix_: F64
    domain_: Domain | None

    def __init__(self, *, constants: SensorConstants = DEFAULT_CONSTANTS,
                 r0_ohm: ArrayLike | None = None, alpha: float = 1e-2,
                 range_margin: float = 0.1) -> None:
        super().__init__(constants=constants, r0_ohm=r0_ohm)
        if not (isinstance(alpha, float | int) and 0.0 < alpha < 1e6):
            raise DecodeError(f"alpha must be in (0, 1e6), got {alpha!r}")
        self.alpha = float(alpha)
        self.range_margin = check_margin(range_margin)

    def fit(self, resistance_ohm: ArrayLike, force_N: ArrayLike, *,
            progress: Progress | None = None) -> Self:
        data = self.training_samples(resistance_ohm, force_N)
        effective, pillars = data.effective_N, data.pillars
        self.unmix_info_ = fit_unmix(*unmix_rows(effective, data.force_N, pillars), self.alpha)
        self.unmix_ = self.unmix_info_.matrix
        self.pillars_ = pillars
        x = features(effective, pillars)
        y = features(self._unmix(x if pillars == 1 else effective), pillars)
        self.domain_ = Domain(Box.fit(x, max(self.range_margin, block_margin(x))),
                              Box.fit(y, max(self.range_margin, block_margin(y))))
        return self

    def meta(self) -> dict[str, Any]:
        info = self.__dict__.get("unmix_info_")
        return super().meta() if info is None else {"crosstalk": info.to_meta()}

    @classmethod
    def _upgrade(cls, params: dict[str, Any], state: dict[str, Any], version: int) -> None:
        params.setdefault("range_margin", 0.1)
        state.setdefault("domain_", None)  # version 1 kept no domain: nothing is flagged

    def _check_state(self) -> None:
        expect_array(self.unmix_, "state.unmix_", (9, 9))
        if self.pillars_ not in (1, 3) or isinstance(self.pillars_, bool):
            raise ModelFileError(f"state.pillars_: must be 1 or 3, got {self.pillars_!r}")
        if self.domain_ is not None:
            size = 9 * self.pillars_
            self.domain_ = Domain.from_state(self.domain_, "state.domain_", size, size)

    def _unmix(self, effective: F64) -> F64:
        """W applied per sample and component: Fz (n, 9) or forces (n, 9, 3) -> forces."""
        return to_force(apply_unmix(self.unmix_, effective), self.pillars_)

    def _decode_fast(self, r: F64) -> F64 | None:
        effective = self.inverse(self.pillars_).fast(r)
        if effective is None:
            return None
        force = self._unmix(effective)
        domain = self.domain_
        if domain is not None and not (
                domain.inputs.all_inside(features(effective, self.pillars_))
                and domain.outputs.all_inside(features(force, self.pillars_))):
            return None
        return force

    def _decode_full(self, r: F64) -> tuple[F64, NDArray[np.uint8]]:
        effective, ok = self.inverse(self.pillars_).full(r)  # 0 N where not ok
        force = self._unmix(effective)
        reason = taxel_reasons(r, ok, self.constants)
        domain = self.domain_
        if domain is not None:
            outside = ~(domain.inputs.inside(features(effective, self.pillars_))
                        & domain.outputs.inside(features(force, self.pillars_)))
            domain_reasons(reason, per_taxel(outside))
        return force, reason
