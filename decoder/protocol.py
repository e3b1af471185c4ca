"""The Decoder protocol, the Decoded result, and the base class every decoder shares."""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol, Self, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from decoder.modelfile import VERSION, read_model, write_model
from decoder.physics import Inverse, make_inverse, solve
from decoder.reasons import reason_name
from skin.constants import DEFAULT_CONSTANTS, TAXELS_PER_PATCH, SensorConstants
from skin.errors import ConfigError, DecodeError, ModelFileError, NotFittedError

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
    needs_fitting: ClassVar[bool]
    """It decodes only once fitted, or loaded from a model file (a learned decoder); a
    decoder that decodes as built (``analytic``) says False."""

    def fit(self, resistance_ohm: ArrayLike, force_N: ArrayLike, *,
            progress: Progress | None = None) -> Self: ...

    def decode(self, resistance_ohm: ArrayLike) -> Decoded: ...

    def save(self, path: str | os.PathLike[str]) -> None: ...

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Self: ...


def fold_resistance(resistance_ohm: ArrayLike) -> tuple[F64, tuple[int, ...]]:
    """(samples, [patches,] 9, P) -> contiguous (n, 9, P) float64, and the leading shape."""
    r = np.asarray(resistance_ohm, dtype=np.float64)
    shape = r.shape
    if len(shape) not in (3, 4) or shape[-2] != TAXELS_PER_PATCH or shape[-1] not in (1, 3):
        raise DecodeError(
            f"resistance_ohm must be (samples, 9, P) or (samples, patches, 9, P) with P = 1 "
            f"(z-only) or 3 (pillars z, x, y), got shape {shape}"
        )
    if len(shape) == 4:
        r = r.reshape(-1, TAXELS_PER_PATCH, shape[-1])
    if not r.flags.c_contiguous:
        r = np.ascontiguousarray(r)
    return r, shape[:-2]


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


@dataclass(frozen=True)
class TrainingSamples:
    """What a learned decoder's ``fit`` starts from: the patch-samples whose nine taxels all
    decode by the exact inverse, folded (``BaseDecoder.training_samples``)."""

    resistance_ohm: F64  # (n, 9, P)
    effective_N: F64  # (n, 9, 3): the exact inverse's forces of those readings
    force_N: F64  # (n, 9, 3): the forces they were measured under
    pillars: int


def unfold(decoded: Decoded, lead: tuple[int, ...]) -> Decoded:
    """Restore the leading shape of :func:`fold_resistance` (a no-op for (samples, 9, P))."""
    if len(lead) == 1:
        return decoded
    shape = (*lead, TAXELS_PER_PATCH)
    return Decoded(decoded.force_N.reshape(*shape, 3), decoded.valid.reshape(shape),
                   decoded.reason.reshape(shape))


def all_valid(force: F64, lead: tuple[int, ...]) -> Decoded:
    """Decoded, in the leading shape ``lead``, for forces (n, 9, 3) of which every taxel decoded."""
    shape = (*lead, TAXELS_PER_PATCH)
    valid = np.empty(shape, dtype=bool)
    valid.fill(True)
    if len(lead) > 1:
        force = force.reshape(*shape, 3)
    return Decoded(force, valid, np.zeros(shape, dtype=np.uint8))


def masked(force: F64, reason: NDArray[np.uint8], lead: tuple[int, ...]) -> Decoded:
    """Decoded, in the leading shape ``lead``, for forces (n, 9, 3) and reasons (n, 9):
    0 N wherever the reason is not OK."""
    valid = reason == 0
    if not valid.all():
        force[~valid] = 0.0
    return unfold(Decoded(force, valid, reason), lead)


class BaseDecoder:
    """Shared parameters, the decode template, fitted-state checks and model-file round trip.

    Subclasses list their constructor keywords in ``_params`` and their learned
    attributes (names ending in "_") in ``_state``; ``_check_state`` validates a
    loaded state so a tampered file cannot become a silently wrong model.

    ``decode`` folds the input and calls ``_check_decodable``, then
    ``_decode_fast``, which returns the forces only if no taxel needs masking
    (else None), and otherwise ``_decode_full``, which returns forces and a
    reason per taxel; ``decode`` then zeroes the masked taxels. The two paths
    must agree exactly wherever the fast one answers
    (tests/decoder/test_fast_path.py); it exists so that one patch-sample does
    not pay for the reason machinery.
    """

    name: ClassVar[str] = ""
    needs_fitting: ClassVar[bool] = False
    _params: ClassVar[tuple[str, ...]] = ("constants", "r0_ohm")
    _state: ClassVar[tuple[str, ...]] = ()
    _loaded_meta: dict[str, Any]

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "needs_fitting" not in cls.__dict__:  # a decoder with learned state needs fitting
            cls.needs_fitting = bool(cls._state)

    def __init__(self, *, constants: SensorConstants = DEFAULT_CONSTANTS,
                 r0_ohm: ArrayLike | None = None) -> None:
        self.constants = constants
        self.r0_ohm = None if r0_ohm is None else np.array(r0_ohm, dtype=np.float64)
        if self.r0_ohm is not None:
            if not (np.all(np.isfinite(self.r0_ohm)) and np.all(self.r0_ohm > 0)):
                raise DecodeError("r0_ohm must be positive and finite")
            self.r0_ohm.flags.writeable = False  # the cached inverses depend on it
        self._inverses: dict[int, Inverse] = {}
        self._inverse_key: tuple[SensorConstants, F64 | None] = (constants, self.r0_ohm)

    def training_samples(self, resistance_ohm: ArrayLike, force_N: ArrayLike) -> TrainingSamples:
        """The opening of every learned decoder's ``fit``: resistances and forces folded, the
        exact inverse applied, and only the samples whose nine taxels all decode kept."""
        r, _ = fold_resistance(resistance_ohm)
        force = fold_force(force_N, r.shape[0])
        pillars = r.shape[-1]
        effective, reason = solve(self.inverse(pillars), r, self.constants)
        keep = np.all(reason == 0, axis=1)
        if not np.any(keep):
            raise DecodeError("no training sample has all nine taxels valid")
        return TrainingSamples(r[keep], effective[keep], force[keep], pillars)

    def r0_for(self, pillars: int) -> F64:
        """R0 broadcastable against (n, 9, P)."""
        if self.r0_ohm is None:
            return self.constants.nominal_resistance_ohm[:pillars]
        r0 = self.r0_ohm
        if r0.shape not in ((pillars,), (TAXELS_PER_PATCH, pillars)):
            raise DecodeError(f"r0_ohm has shape {r0.shape}; expected ({pillars},) or "
                              f"(9, {pillars}) for {pillars}-pillar input")
        return r0

    def inverse(self, pillars: int) -> Inverse:
        """The exact inverse for these constants and R0, built on first use per pillar count."""
        key = self._inverse_key
        if key[0] is not self.constants or key[1] is not self.r0_ohm:
            self._inverses = {}
            self._inverse_key = (self.constants, self.r0_ohm)
        inverse = self._inverses.get(pillars)
        if inverse is None:
            inverse = make_inverse(self.constants, self.r0_for(pillars), pillars)
            self._inverses[pillars] = inverse
        return inverse

    def decode(self, resistance_ohm: ArrayLike) -> Decoded:
        """Resistances (samples, [patches,] 9, P) in ohm -> forces, valid mask and reasons."""
        r, lead = fold_resistance(resistance_ohm)
        self._check_decodable(r.shape[2])
        force = self._decode_fast(r)
        if force is not None:
            return all_valid(force, lead)
        force, reason = self._decode_full(r)
        return masked(force, reason, lead)

    def _check_decodable(self, pillars: int) -> None:
        """Raise unless fitted (decoders with state), on ``pillars``-pillar input if it says."""
        if self._state and "pillars_" not in self.__dict__:
            self._require_fitted()
        fitted = self.__dict__.get("pillars_", pillars)
        if pillars != fitted:
            raise DecodeError(f"model was fitted on {fitted}-pillar input, got {pillars} pillars")

    def _decode_fast(self, r: F64) -> F64 | None:
        """Folded (n, 9, P) -> forces (n, 9, 3) if no taxel needs masking, else None."""
        return None

    def _decode_full(self, r: F64) -> tuple[F64, NDArray[np.uint8]]:
        """Folded (n, 9, P) -> forces (n, 9, 3) and reasons (n, 9) for any input; the forces
        of taxels with a reason are set to 0 N by ``decode``."""
        raise NotImplementedError

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
        state = {s: self._state_value(s) for s in self._state}
        write_model(path, self.name, params, state, self.meta())

    def _state_value(self, key: str) -> Any:
        """A learned attribute as the model file holds it: objects with ``to_state()`` (a
        training domain) as what that returns."""
        value = getattr(self, key)
        to_state = getattr(value, "to_state", None)
        return value if to_state is None else to_state()

    def meta(self) -> dict[str, Any]:
        """What the model file's ``meta`` holds: how training went (empty if nothing to say).

        After :meth:`load` it is the file's own ``meta``."""
        loaded: dict[str, Any] = self.__dict__.get("_loaded_meta", {})
        return loaded

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Self:
        content = read_model(path)
        if content.name != cls.name:
            raise ModelFileError(f"name: file holds a {content.name!r} model, not {cls.name!r}")
        return cls.from_content(content.params, content.state, os.fspath(path),
                                version=content.version, meta=content.meta)

    @classmethod
    def _upgrade(cls, params: dict[str, Any], state: dict[str, Any], version: int) -> None:
        """Bring an older file's params and state to the current layout, in place."""

    @classmethod
    def from_content(cls, params: dict[str, Any], state: dict[str, Any], where: str, *,
                     version: int = VERSION, meta: dict[str, Any] | None = None) -> Self:
        params, state = dict(params), dict(state)
        if version < VERSION and set(state) != set(cls._state):
            cls._upgrade(params, state, version)
        if set(params) != set(cls._params):
            raise ModelFileError(f"{where}: params: expected keys {sorted(cls._params)}, "
                                 f"got {sorted(params)}")
        if set(state) != set(cls._state):
            raise ModelFileError(f"{where}: state: expected keys {sorted(cls._state)}, "
                                 f"got {sorted(state)}")
        kwargs = dict(params)
        try:
            kwargs["constants"] = SensorConstants.from_dict(kwargs["constants"],
                                                            "params.constants")
        except ConfigError as err:
            raise ModelFileError(f"{where}: {err}") from err
        try:
            model = cls(**kwargs)
        except (TypeError, ValueError, ArithmeticError) as err:
            raise ModelFileError(f"{where}: params.{cls._culprit(kwargs)}: {err}") from err
        for key, value in state.items():
            setattr(model, key, value)
        try:
            model._check_state()
        except ModelFileError as err:
            raise ModelFileError(f"{where}: {err}") from err
        model._loaded_meta = dict(meta or {})
        return model

    @classmethod
    def _culprit(cls, kwargs: dict[str, Any]) -> str:
        """The parameter that makes ``cls(**kwargs)`` fail: the first one that fails alone."""
        for key, value in kwargs.items():
            if key == "constants":
                continue
            try:
                cls(constants=kwargs["constants"], **{key: value})
            except (TypeError, ValueError, ArithmeticError):
                return key
        return "(their combination)"

    def _check_state(self) -> None:
        """Validate loaded state; subclasses raise ModelFileError("state.<field>: ...")."""

    def __repr__(self) -> str:
        shown = ", ".join(f"{p}={getattr(self, p)!r}" for p in self._params if p != "constants")
        return f"{type(self).__name__}({shown})"
