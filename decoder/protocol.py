"""The Decoder protocol, the Decoded result, and the base class every decoder shares."""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol, Self, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from decoder.modelfile import read_model, write_model
from decoder.reasons import reason_name
from skin.constants import DEFAULT_CONSTANTS, TAXELS_PER_PATCH, SensorConstants
from skin.errors import DecodeError, ModelFileError, NotFittedError

F64 = NDArray[np.float64]
Progress = Callable[[int, float, float], None]
"""Training progress callback: (epoch, training MSE, mu)."""


@dataclass(frozen=True)
class Decoded:
    """Forces of one batch: force_N (..., 9, 3) as (Fx, Fy, Fz), valid and reason (..., 9).

    Invalid taxels carry 0 N, valid False and a non-zero :class:`~decoder.reasons.Reason`;
    force_N never holds NaN or infinity.
    """

    force_N: F64
    valid: NDArray[np.bool_]
    reason: NDArray[np.uint8]

    def reason_names(self) -> NDArray[np.str_]:
        """The reason codes as names ("OK", "OPEN", ...), same shape as ``reason``."""
        names: NDArray[np.str_] = np.vectorize(reason_name, otypes=[str])(self.reason)
        return names


@runtime_checkable
class Decoder(Protocol):
    """Resistances (samples, 9, P) or (samples, patches, 9, P) in ohm -> forces."""

    name: ClassVar[str]

    def fit(self, resistance_ohm: ArrayLike, force_N: ArrayLike, *,
            progress: Progress | None = None) -> Self: ...

    def decode(self, resistance_ohm: ArrayLike) -> Decoded: ...

    def save(self, path: str | os.PathLike[str]) -> None: ...

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Self: ...


def fold_resistance(resistance_ohm: ArrayLike) -> tuple[F64, tuple[int, ...]]:
    """(samples, [patches,] 9, P) -> contiguous (n, 9, P) float64, and the leading shape."""
    r = np.asarray(resistance_ohm, dtype=np.float64)
    if r.ndim not in (3, 4) or r.shape[-2] != TAXELS_PER_PATCH or r.shape[-1] not in (1, 3):
        raise DecodeError(
            f"resistance_ohm must be (samples, 9, P) or (samples, patches, 9, P) with P = 1 "
            f"(z-only) or 3 (pillars z, x, y), got shape {r.shape}"
        )
    lead = r.shape[:-2]
    return np.ascontiguousarray(r.reshape(-1, TAXELS_PER_PATCH, r.shape[-1])), lead


def fold_force(force_N: ArrayLike, samples: int) -> F64:
    """Forces matching folded resistances: (n, 9, 3), finite."""
    f = np.asarray(force_N, dtype=np.float64)
    if f.shape[-2:] != (TAXELS_PER_PATCH, 3) or f.ndim not in (3, 4):
        raise DecodeError(f"force_N must be (samples, [patches,] 9, 3), got shape {f.shape}")
    f = f.reshape(-1, TAXELS_PER_PATCH, 3)
    if f.shape[0] != samples:
        raise DecodeError(f"force_N has {f.shape[0]} patch-samples, resistances {samples}")
    if not np.all(np.isfinite(f)):
        raise DecodeError("force_N contains NaN or infinity")
    return f


def unfold(decoded: Decoded, lead: tuple[int, ...]) -> Decoded:
    return Decoded(
        force_N=decoded.force_N.reshape(*lead, TAXELS_PER_PATCH, 3),
        valid=decoded.valid.reshape(*lead, TAXELS_PER_PATCH),
        reason=decoded.reason.reshape(*lead, TAXELS_PER_PATCH),
    )


def finalize(force: F64, reason: NDArray[np.uint8]) -> Decoded:
    """Zero the force of every invalid taxel and of any non-finite output; build Decoded."""
    bad = ~np.all(np.isfinite(force), axis=-1)
    if np.any(bad):
        from decoder.reasons import Reason

        reason = np.where(bad & (reason == 0), np.uint8(Reason.OUT_OF_RANGE), reason)
    valid = reason == 0
    force = np.where(valid[..., None], force, 0.0)
    return Decoded(force_N=force, valid=valid, reason=reason.astype(np.uint8))


class BaseDecoder:
    """Shared parameters, fitted-state checks and model-file round trip.

    Subclasses list their constructor keywords in ``_params`` and their learned
    attributes (names ending in "_") in ``_state``; ``_check_state`` validates a
    loaded state so a tampered file cannot become a silently wrong model.
    """

    name: ClassVar[str] = ""
    _params: ClassVar[tuple[str, ...]] = ("constants", "r0_ohm")
    _state: ClassVar[tuple[str, ...]] = ()

    def __init__(self, *, constants: SensorConstants = DEFAULT_CONSTANTS,
                 r0_ohm: ArrayLike | None = None) -> None:
        self.constants = constants
        self.r0_ohm = None if r0_ohm is None else np.asarray(r0_ohm, dtype=np.float64)
        if self.r0_ohm is not None and not (
            np.all(np.isfinite(self.r0_ohm)) and np.all(self.r0_ohm > 0)
        ):
            raise DecodeError("r0_ohm must be positive and finite")

    def r0_for(self, pillars: int) -> F64:
        """R0 broadcastable against (n, 9, P)."""
        if self.r0_ohm is None:
            return self.constants.nominal_resistance_ohm[:pillars]
        r0 = self.r0_ohm
        if r0.shape not in ((pillars,), (TAXELS_PER_PATCH, pillars)):
            raise DecodeError(f"r0_ohm has shape {r0.shape}; expected ({pillars},) or "
                              f"(9, {pillars}) for {pillars}-pillar input")
        return r0

    def _require_fitted(self) -> None:
        missing = [s for s in self._state if not hasattr(self, s)]
        if missing:
            raise NotFittedError(f"{type(self).__name__} is not fitted yet: call fit() first")

    def get_params(self) -> dict[str, Any]:
        return {p: getattr(self, p) for p in self._params}

    def save(self, path: str | os.PathLike[str]) -> None:
        self._require_fitted()
        params = self.get_params()
        params["constants"] = self.constants.to_dict()
        state = {s: getattr(self, s) for s in self._state}
        write_model(path, self.name, params, state)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Self:
        content = read_model(path)
        if content.name != cls.name:
            raise ModelFileError(f"name: file holds a {content.name!r} model, not {cls.name!r}")
        return cls.from_content(content.params, content.state, os.fspath(path))

    @classmethod
    def from_content(cls, params: dict[str, Any], state: dict[str, Any], where: str) -> Self:
        if set(params) != set(cls._params):
            raise ModelFileError(f"{where}: params: expected keys {sorted(cls._params)}, "
                                 f"got {sorted(params)}")
        if set(state) != set(cls._state):
            raise ModelFileError(f"{where}: state: expected keys {sorted(cls._state)}, "
                                 f"got {sorted(state)}")
        kwargs = dict(params)
        try:
            if not isinstance(kwargs["constants"], dict):
                raise TypeError("must be a map")
            kwargs["constants"] = SensorConstants.from_dict(kwargs["constants"])
            model = cls(**kwargs)
        except (TypeError, ValueError) as err:
            raise ModelFileError(f"{where}: params: {err}") from err
        for key, value in state.items():
            setattr(model, key, value)
        try:
            model._check_state()
        except ModelFileError as err:
            raise ModelFileError(f"{where}: {err}") from err
        return model

    def _check_state(self) -> None:
        """Validate loaded state; subclasses raise ModelFileError("state.<field>: ...")."""

    def __repr__(self) -> str:
        shown = ", ".join(f"{p}={getattr(self, p)!r}" for p in self._params if p != "constants")
        return f"{type(self).__name__}({shown})"


def expect_array(value: Any, field: str, shape: tuple[int, ...]) -> F64:
    """State check helper: a float64 array of exactly ``shape``."""
    if not isinstance(value, np.ndarray) or value.dtype != np.float64 or value.shape != shape:
        got = value.shape if isinstance(value, np.ndarray) else type(value).__name__
        raise ModelFileError(f"state.{field}: expected float64 array of shape {shape}, got {got}")
    return value
