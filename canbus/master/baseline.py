"""Tare and baseline-drift tracking, host side: the resistance scale of one patch.

The data plane multiplies each patch's resistances by ``scale = r0_ref / baseline``
(per taxel and pillar) before decoding, where ``r0_ref`` is the resistance at which the
decoder reads zero force and ``baseline`` the patch's resistance at rest. Initially the
baseline is the R0 the patch reports (0x2002): for the analytic decoder built with the
patch's constants that is a scale of one.

* :meth:`Baseline.tare` takes the last complete raw sample as the new rest: the patch
  reads zero force there. It is refused (:class:`PatchLoadedError`) while any taxel
  reads more than ``loaded_N``: taring under load would subtract a real force forever.
* :meth:`Baseline.track` (drift tracking) moves the baseline of each taxel *not in
  contact* towards its raw reading by an exponential moving average with time constant
  ``time_constant_s``; a taxel in contact (|F| > ``contact_N``) or invalid keeps its
  baseline frozen, so a steady contact keeps its force instead of fading to zero.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skin.errors import SkinError

F64 = NDArray[np.float64]


class PatchLoadedError(SkinError, RuntimeError):
    """Tare was asked for while the patch is loaded (or before it sent a sample)."""


class Baseline:
    """The rest resistances of one patch and the scale they give; thread-safe."""

    def __init__(self, r0_ref: ArrayLike, baseline: ArrayLike, *, loaded_N: float,
                 time_constant_s: float | None = None, contact_N: float = 0.1,
                 on_scale: Callable[[F64], None] | None = None) -> None:
        self.r0_ref = np.broadcast_to(np.asarray(r0_ref, dtype=np.float64),
                                      np.shape(baseline)).copy()
        start = np.asarray(baseline, dtype=np.float64).copy()
        # A reported R0 that is the reference to within its mOhm rounding is the reference.
        same = np.abs(start - self.r0_ref) <= 0.5e-3  # half a count of 0x2002
        self.baseline = np.where(same, self.r0_ref, start)
        if not np.all(np.isfinite(self.baseline) & (self.baseline > 0)):
            raise ValueError("baseline resistances must be positive and finite")
        self.loaded_N = loaded_N
        self.time_constant_s = time_constant_s
        self.contact_N = contact_N
        self._lock = threading.Lock()
        self._on_scale = on_scale
        self.scale: F64 = self.r0_ref / self.baseline
        if on_scale is not None:
            on_scale(self.scale)

    def _publish(self) -> F64:
        """New scale from the baseline, handed to ``on_scale`` under the lock (in order)."""
        self.scale = self.r0_ref / self.baseline
        if self._on_scale is not None:
            self._on_scale(self.scale)
        return self.scale

    def tare(self, raw_ohm: ArrayLike | None, force_N: ArrayLike | None,
             valid: ArrayLike | None, *, node_id: int) -> F64:
        """Re-zero at ``raw_ohm`` (9, P); returns the new scale. Taxels without a usable
        reading (invalid, non-finite) keep their baseline."""
        if raw_ohm is None or force_N is None or valid is None:
            raise PatchLoadedError(f"patch {node_id}: no complete sample yet to tare on")
        magnitude = np.linalg.norm(np.asarray(force_N, dtype=np.float64), axis=-1)
        loaded = np.flatnonzero(np.asarray(valid, dtype=bool) & (magnitude > self.loaded_N))
        if loaded.size:
            listed = ", ".join(f"taxel {k} {magnitude[k]:.3g} N" for k in loaded.tolist())
            raise PatchLoadedError(f"patch {node_id} is loaded ({listed} > "
                                   f"{self.loaded_N:g} N): tare refused; unload it first")
        raw = np.asarray(raw_ohm, dtype=np.float64)
        usable = np.isfinite(raw) & (raw > 0) & np.asarray(valid, dtype=bool)[:, None]
        with self._lock:
            self.baseline = np.where(usable, raw, self.baseline)
            return self._publish()

    def track(self, raw_ohm: ArrayLike, force_N: ArrayLike, valid: ArrayLike,
              dt_s: float) -> F64:
        """One drift-tracking step of ``dt_s`` seconds; returns the new scale."""
        if self.time_constant_s is None:
            return self.scale
        alpha = min(1.0, dt_s / self.time_constant_s)
        raw = np.asarray(raw_ohm, dtype=np.float64)
        magnitude = np.linalg.norm(np.asarray(force_N, dtype=np.float64), axis=-1)
        free = np.asarray(valid, dtype=bool) & (magnitude <= self.contact_N)
        usable = free[:, None] & np.isfinite(raw) & (raw > 0)
        with self._lock:
            self.baseline = np.where(usable, self.baseline + alpha * (raw - self.baseline),
                                     self.baseline)
            return self._publish()
