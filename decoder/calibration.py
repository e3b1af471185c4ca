"""Choosing and fitting a patch's own decoder: k-fold validation on its calibration data.

Every candidate decoder is fitted on k - 1 folds and decodes the one left out, for each
of the k folds; the folds are contiguous stretches of the data (a held-out fold is a
stretch the model never saw, not samples interleaved with its training ones, which in a
recording of slow presses would be near copies). The out-of-fold forces of all k folds
give each candidate's held-out figures: the floored AveRelErr (|F| >= 5 % of full
scale), the plain one (Eq. 22), RMSE per axis, a per-taxel map, and the share of taxels
the decoder refused (EXTRAPOLATED and the like).

The best candidate has the lowest held-out floored error among those that refuse at
most ``max_flagged`` of the held-out taxels; a candidate within ``tie`` (relative) of it
and faster per patch-sample wins the tie. It is refitted on all the data.

Pure arrays: the caller normalises the readings to the decoders' frame
(:mod:`decoder.tare`) and writes the model.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from decoder.metrics import FLOOR_FRACTION, evaluate
from decoder.protocol import BaseDecoder, Decoder
from decoder.registry import available_decoders, create_decoder, decoder_class
from decoder.speed import decode_speed
from skin.constants import TAXELS_PER_PATCH, SensorConstants
from skin.errors import ConfigError, DecodeError, ModelFileError

F64 = NDArray[np.float64]
DEFAULT_FOLDS = 5
DEFAULT_TIE = 0.02
DEFAULT_MAX_FLAGGED = 0.005
AXES = ("Fx", "Fy", "Fz")
Stage = Callable[[str, int, int], None]
"""Progress: (what is being done, steps done, steps in all)."""
Epochs = Callable[[int, float, float], None]
"""A fit's epoch progress: (epoch, training MSE, mu), as ``Decoder.fit`` reports it."""


def default_candidates() -> tuple[str, ...]:
    """``analytic`` and every registered decoder that learns (its class keeps fitted state)."""
    out = ["analytic"]
    for name in available_decoders():
        cls = decoder_class(name)
        if name != "analytic" and issubclass(cls, BaseDecoder) and cls.needs_fitting:
            out.append(name)
    return tuple(out)


def parse_candidate(spec: str) -> tuple[str, int | str | None]:
    """``NAME`` or ``NAME:HIDDEN`` (a number of hidden nodes, or ``auto``) -> (name, hidden);
    the decoder must be registered and, with HIDDEN, take hidden nodes."""
    name, sep, hidden = spec.partition(":")
    cls = decoder_class(name)
    if not sep:
        return name, None
    if "hidden" not in getattr(cls, "_params", ()):
        raise ConfigError("--decoders", f"{spec!r}: decoder {name!r} has no hidden nodes")
    if hidden == "auto":
        return name, hidden
    if not hidden.isdigit() or not 1 <= int(hidden) <= 1000:
        raise ConfigError("--decoders", f"{spec!r}: hidden nodes must be 1..1000 or auto")
    return name, int(hidden)


def make_decoder(spec: str, constants: SensorConstants, *, hidden: int | str | None = None,
                 seed: int | None = None) -> Decoder:
    """A fresh decoder for the candidate ``spec`` (``NAME[:HIDDEN]``) with the patch's
    constants, and ``hidden`` (unless the spec names its own) and ``seed`` where it takes
    them."""
    name, own = parse_candidate(spec)
    hidden = own if own is not None else hidden
    cls = decoder_class(name)
    params: dict[str, Any] = {}
    accepted = getattr(cls, "_params", ())
    if "constants" in accepted or not accepted:
        params["constants"] = constants
    if hidden is not None and "hidden" in accepted:
        params["hidden"] = hidden
    if seed is not None and "seed" in accepted:
        params["seed"] = seed
    try:
        return create_decoder(name, **params)
    except TypeError:  # a plug-in that takes no sensor constants
        return create_decoder(name)


def folds_of(samples: int, folds: int) -> list[NDArray[np.intp]]:
    """``folds`` contiguous, nearly equal stretches of ``range(samples)``."""
    if not 2 <= folds <= samples:
        raise ConfigError("--folds", f"must be in 2..{samples} (the samples), got {folds}")
    return [np.asarray(a, dtype=np.intp) for a in np.array_split(np.arange(samples), folds)]


@dataclass
class Candidate:
    """One decoder's held-out figures."""

    name: str
    hidden: int | None
    heldout_floored_pct: float
    heldout_ave_rel_err_pct: float
    rmse_N: float
    rmse_axis_N: F64  # (3,) Fx, Fy, Fz over compared components (NaN: none)
    per_taxel_floored_pct: F64  # (9,) NaN where a taxel has no floored component
    per_taxel_floored_count: NDArray[np.int64]  # (9,)
    per_taxel_rmse_N: F64  # (9,)
    fold_floored_pct: F64  # (folds,)
    flagged: float  # share of held-out taxels refused
    fit_s: float  # mean per fold
    latency_us: float = math.nan  # one patch-sample
    rate: float = math.nan  # patch-samples/s, batched
    eligible: bool = True
    why: str = ""

    def summary(self) -> dict[str, Any]:
        return {"decoder": self.name, "hidden": self.hidden,
                "heldout_floored_pct": _num(self.heldout_floored_pct),
                "heldout_ave_rel_err_pct": _num(self.heldout_ave_rel_err_pct),
                "rmse_N": _num(self.rmse_N), "flagged_pct": 100.0 * self.flagged,
                "fold_floored_pct": [_num(v) for v in self.fold_floored_pct.tolist()],
                "fit_s": self.fit_s, "latency_us": _num(self.latency_us),
                "patch_samples_per_s": _num(self.rate), "eligible": self.eligible,
                "why_not": self.why or None}


@dataclass
class Calibration:
    """What :func:`calibrate` chose and fitted."""

    decoder: Decoder
    best: Candidate
    candidates: list[Candidate]
    folds: int
    samples: int
    mode: str
    domain: dict[str, Any] = field(default_factory=dict)
    analytic_latency_us: float = math.nan


def _num(value: float) -> float | None:
    return None if not math.isfinite(value) else float(value)


def heldout(name: str, x: F64, force: F64, folds: list[NDArray[np.intp]], constants:
            SensorConstants, mode: str, *, hidden: int | str | None = None,
            seed: int | None = None, on_fold: Callable[[int], None] | None = None,
            epochs: Epochs | None = None) -> tuple[Candidate, Decoder]:
    """``name``'s out-of-fold figures, and its decoder of the last fold (for its speed)."""
    n = x.shape[0]
    pred = np.zeros((n, TAXELS_PER_PATCH, 3))
    valid = np.zeros((n, TAXELS_PER_PATCH), dtype=bool)
    fold_floored, fit_s = [], []
    decoder: Decoder | None = None
    for k, test in enumerate(folds):
        train = np.setdiff1d(np.arange(n), test, assume_unique=True)
        decoder = make_decoder(name, constants, hidden=hidden, seed=seed)
        start = time.perf_counter()
        decoder.fit(x[train], force[train], progress=epochs)
        fit_s.append(time.perf_counter() - start)
        out = decoder.decode(x[test])
        pred[test], valid[test] = out.force_N, out.valid
        fold_floored.append(evaluate(force[test], out.force_N, out.valid, mode=mode,
                                     constants=constants).ave_rel_err_floored_pct)
        if on_fold is not None:
            on_fold(k + 1)
    assert decoder is not None
    report = evaluate(force, pred, valid, mode=mode, constants=constants)
    axis, taxel_pct, taxel_count, taxel_rmse = _maps(force, pred, valid, mode, constants)
    candidate = Candidate(
        name=name, hidden=_hidden(decoder), heldout_floored_pct=report.ave_rel_err_floored_pct,
        heldout_ave_rel_err_pct=report.ave_rel_err_pct, rmse_N=report.rmse_N,
        rmse_axis_N=axis, per_taxel_floored_pct=taxel_pct, per_taxel_floored_count=taxel_count,
        per_taxel_rmse_N=taxel_rmse, fold_floored_pct=np.array(fold_floored),
        flagged=float(1.0 - valid.mean()), fit_s=float(np.mean(fit_s)))
    return candidate, decoder


def _hidden(decoder: Decoder) -> int | None:
    hidden = getattr(decoder, "hidden_", None)
    return int(hidden) if isinstance(hidden, int | np.integer) else None


def _maps(force: F64, pred: F64, valid: NDArray[np.bool_], mode: str,
          constants: SensorConstants) -> tuple[F64, F64, NDArray[np.int64], F64]:
    """RMSE per axis; floored AveRelErr %, its component count and RMSE per taxel."""
    axes = (2,) if mode == "z" else (0, 1, 2)
    err = pred - force
    ok = np.broadcast_to(valid[..., None], force.shape)
    axis = np.full(3, np.nan)
    for a in axes:
        e = err[..., a][valid]
        axis[a] = math.sqrt(float(np.mean(e * e))) if e.size else math.nan
    floor = FLOOR_FRACTION * constants.full_scale_force_N
    chosen = np.zeros(3, dtype=bool)
    chosen[list(axes)] = True
    use = ok & chosen
    floored = use & (np.abs(force) >= floor)
    rel = np.where(floored, np.abs(err) / np.where(floored, np.abs(force), 1.0), 0.0)
    count = floored.sum(axis=(0, 2)).astype(np.int64)
    with np.errstate(invalid="ignore", divide="ignore"):
        pct = np.where(count > 0, 100.0 * rel.sum(axis=(0, 2)) / count, np.nan)
        sq = np.where(use, err * err, 0.0).sum(axis=(0, 2))
        used = use.sum(axis=(0, 2))
        rmse = np.where(used > 0, np.sqrt(sq / np.maximum(used, 1)), np.nan)
    return axis, pct, count, rmse


def choose(candidates: Sequence[Candidate], *, tie: float = DEFAULT_TIE,
           max_flagged: float = DEFAULT_MAX_FLAGGED) -> Candidate:
    """The lowest held-out floored error among the eligible; ties (within ``tie``, relative)
    go to the fastest per patch-sample."""
    for c in candidates:
        if not math.isfinite(c.heldout_floored_pct):
            c.eligible, c.why = False, "no held-out force above the floor was decoded"
        elif c.flagged > max_flagged:
            c.eligible, c.why = False, (f"refused {100 * c.flagged:.2f} % of the held-out "
                                        f"taxels (at most {100 * max_flagged:g} %)")
    eligible = [c for c in candidates if c.eligible]
    if not eligible:
        raise DecodeError("no candidate decoder qualifies: " + "; ".join(
            f"{c.name}: {c.why}" for c in candidates))
    best = min(c.heldout_floored_pct for c in eligible)
    tied = [c for c in eligible if c.heldout_floored_pct <= best * (1.0 + tie)]
    return min(tied, key=lambda c: (c.latency_us if math.isfinite(c.latency_us) else math.inf,
                                    c.heldout_floored_pct))


def training_domain(x: F64, force: F64, mode: str) -> dict[str, Any]:
    """The ranges the model was fitted on: normalised readings per pillar, forces per axis."""
    p = x.shape[-1]
    return {"samples": int(x.shape[0]),
            "resistance_min_ohm": x.reshape(-1, p).min(axis=0),
            "resistance_max_ohm": x.reshape(-1, p).max(axis=0),
            "force_min_N": force.reshape(-1, 3).min(axis=0),
            "force_max_N": force.reshape(-1, 3).max(axis=0),
            "axes": "Fz" if mode == "z" else "Fx Fy Fz"}


def calibrate(x: F64, force: F64, constants: SensorConstants, *,
              names: Sequence[str] | None = None, folds: int = DEFAULT_FOLDS,
              hidden: int | str | None = None, seed: int | None = None,
              tie: float = DEFAULT_TIE, max_flagged: float = DEFAULT_MAX_FLAGGED,
              stage: Stage | None = None, epochs: Epochs | None = None) -> Calibration:
    """Fit every candidate by k-fold, choose, refit the best on all of ``x`` (n, 9, P)
    normalised readings and ``force`` (n, 9, 3)."""
    names = tuple(names) if names else default_candidates()
    for name in names:
        parse_candidate(name)  # an unknown name fails before any fit
    if len(set(names)) != len(names):
        raise ConfigError("--decoders", "a decoder is named twice")
    mode = "z" if x.shape[-1] == 1 else "xyz"
    stretches = folds_of(x.shape[0], folds)
    total = len(names) * folds + 1

    def step(what: str, done: int) -> None:
        if stage is not None:
            stage(what, done, total)

    candidates = []
    speed_sample = x[: min(x.shape[0], 64)]
    for i, name in enumerate(names):
        step(f"{name}: fold 1 of {folds}", i * folds)

        def fold_done(k: int, name: str = name, before: int = i * folds) -> None:
            step(f"{name}: fold {k + 1} of {folds}" if k < folds else f"{name}: its speed",
                 before + k)

        candidate, last = heldout(name, x, force, stretches, constants, mode, hidden=hidden,
                                  seed=seed, on_fold=fold_done, epochs=epochs)
        candidate.rate, candidate.latency_us = decode_speed(last, speed_sample, 4096, 2)
        candidates.append(candidate)
    analytic = make_decoder("analytic", constants)
    _, analytic_us = decode_speed(analytic, speed_sample, 4096, 2)
    best = choose(candidates, tie=tie, max_flagged=max_flagged)
    step(f"{best.name}: fitting on all {x.shape[0]} samples", total - 1)
    decoder = make_decoder(best.name, constants, hidden=hidden, seed=seed)
    decoder.fit(x, force, progress=epochs)
    step("done", total)
    return Calibration(decoder, best, candidates, folds, int(x.shape[0]), mode,
                       training_domain(x, force, mode), analytic_us)


def report(cal: Calibration, tare_ohm: F64 | None, rest_samples: int, rest_N: float,
           noise_ohm: F64 | None = None) -> dict[str, Any]:
    """The calibration report: plain values and numpy arrays (NaN where undefined)."""
    best = cal.best
    axes = (2,) if cal.mode == "z" else (0, 1, 2)
    return {
        "decoder": cal.decoder.name, "candidate": best.name, "hidden": _hidden(cal.decoder),
        "heldout_floored_pct": best.heldout_floored_pct,
        "heldout_ave_rel_err_pct": best.heldout_ave_rel_err_pct,
        "rmse_N": best.rmse_N,
        "rmse_axis_N": {AXES[a]: float(best.rmse_axis_N[a]) for a in axes},
        "per_taxel_floored_pct": best.per_taxel_floored_pct,
        "per_taxel_floored_count": best.per_taxel_floored_count,
        "per_taxel_rmse_N": best.per_taxel_rmse_N,
        "flagged_pct": 100.0 * best.flagged,
        "folds": cal.folds, "samples": cal.samples, "mode": cal.mode,
        "speed": {"latency_us": best.latency_us, "patch_samples_per_s": best.rate,
                  "analytic_latency_us": cal.analytic_latency_us,
                  "x_analytic": best.latency_us / cal.analytic_latency_us},
        "tare": {"rest_ohm": tare_ohm, "samples": rest_samples, "rest_N": rest_N,
                 "noise_ohm": noise_ohm},
        "domain": cal.domain,
        "candidates": [c.summary() for c in cal.candidates],
    }


def check_calibration_meta(own: Any, where: str) -> dict[str, Any]:
    """A model file's ``meta.calibration`` (written by ``skin calibrate``) with every field
    ``skin calibrate --check`` reads typed and ranged; ModelFileError naming the field."""
    from skin.inputs import fields

    if not isinstance(own, dict) or "heldout_floored_pct" not in own:
        raise ModelFileError(f"{where}: has no calibration report (it was not written by "
                             "skin calibrate)")
    field = "meta.calibration"
    try:
        fields.number(own["heldout_floored_pct"], f"{field}.heldout_floored_pct", 0.0, 1e6)
        fields.number(own.get("flagged_pct", 0.0), f"{field}.flagged_pct", 0.0, 100.0)
        if own.get("mode") not in ("z", "xyz"):
            raise ConfigError(f"{field}.mode", f"must be z or xyz, got {own.get('mode')!r}")
        if own.get("node_id") is not None:
            fields.node_id(own["node_id"], f"{field}.node_id")
        tare = fields.table(own.get("tare", {}), f"{field}.tare")
        fields.number(tare.get("rest_N", 0.01), f"{field}.tare.rest_N", 0.0, 1e4)
        rest = tare.get("rest_ohm")
        pillars = 1 if own["mode"] == "z" else 3
        if rest is not None and not (isinstance(rest, np.ndarray) and rest.shape in (
                (pillars,), (TAXELS_PER_PATCH, pillars)) and np.all(rest > 0)):
            raise ConfigError(f"{field}.tare.rest_ohm", f"must be positive resistances of "
                              f"shape (9, {pillars})")
    except ConfigError as err:
        raise ModelFileError(f"{where}: {err}") from err
    return own
