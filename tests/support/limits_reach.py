"""How far lm-mlp's checks of the whole patch can reach, with hindsight.

For scene pairs drawn by :func:`skin.benchmarks.pairs.random_pair` (1000 training and 300 test
samples, as ``skin bench cross --random``), lm-mlp is trained once and the three limits of its
checks (the pattern of the physics reading, the patch's departure, each taxel's relative
departure) are then scaled by every combination of ``MULTIPLES``, the boxes kept. A pair is
*reachable* when some combination, chosen with its home and away test sets in hand, meets both
halves of the promise (:mod:`skin.benchmarks.judge`); a *common* setting is one combination for
every pair. A training set of a few long episodes has no departure check
(:mod:`decoder.patchcheck`): one is fitted here on its training rows, only to be scaled.

``--window W`` adds a check of the stream: every taxel of a sample is flagged while the
median, over the last W samples, of the sample's mean relative departure (over its loaded
taxels) is above its largest value on the home test set: a limit no fit could know.
Usable as a script::

    python -m tests.support.limits_reach --pairs 120 --jobs 2 [--window 30] [--json F]
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from decoder.lmmlp import LMMLPDecoder
from decoder.metrics import FLOOR_FRACTION
from decoder.patchcheck import DepartureCheck, relative_departure
from decoder.physics import features
from decoder.reasons import Reason
from decoder.registry import create_decoder
from decoder.unmix import apply_unmix
from skin.atomic import atomic_write
from skin.benchmarks.judge import HOME_SHARE, bar_pct, floored
from skin.benchmarks.pairs import ScenePair, pair_data, random_pair
from skin.commands.common.argtypes import count

F64 = NDArray[np.float64]
Mask = NDArray[np.bool_]
MULTIPLES = 2.0 ** np.arange(-4, 9)
"""1/16 to 256 times each limit; the departure limits also infinite (their check off)."""
LIFTED = 1e300


@dataclass(frozen=True)
class Side:
    """One test set decoded with the three limits lifted, and what each check measures."""

    boxed: Mask  # (n, 9) flagged by the boxes alone
    valid: Mask  # (n, 9) decoded with the limits lifted
    whole: Mask  # (n,) every taxel has a physics reading: the checks apply
    pattern: F64  # (n,) squared pattern distance
    patch: F64  # (n,) squared distance of the patch's departure
    taxel: F64  # (n, 9) relative departure
    err_sum: F64  # (n, 9) the floored components' relative errors, summed per taxel
    err_count: NDArray[np.intp]  # (n, 9) floored components per taxel


@dataclass(frozen=True)
class PairStats:
    index: int
    label: str
    episodes: bool
    deconv_away_pct: float | None
    limits: tuple[float, float, float]
    home: Side
    away: Side


def _departure(dec: LMMLPDecoder, r: F64) -> tuple[F64, F64, Mask]:
    """The network's departure from the physics reading (n, 9·P), the physics reading, and
    which taxels have one (n, 9), as decode computes them (readings outside the box clamped
    into it)."""
    assert dec.unmix_ is not None
    effective, ok = dec.inverse(dec.pillars_).full(r)
    physics = features(apply_unmix(dec.unmix_, effective), dec.pillars_)
    return dec._net(dec.domain_.inputs.clamp(r.reshape(r.shape[0], -1))) - physics, physics, ok


def _side(dec: LMMLPDecoder, check: DepartureCheck, r: F64, force: F64, mode: str) -> Side:
    assert dec.domain_.pattern is not None
    decoded = dec.decode(r)
    departure, physics, ok = _departure(dec, r)
    comps = slice(2, 3) if mode == "z" else slice(0, 3)
    true, got = force[..., comps], decoded.force_N[..., comps]
    loaded = np.abs(true) >= FLOOR_FRACTION * dec.constants.full_scale_force_N
    rel = np.where(loaded, np.abs(got - true) / np.where(loaded, np.abs(true), 1.0), 0.0)
    return Side(decoded.reason == Reason.EXTRAPOLATED, decoded.valid, np.asarray(ok.all(axis=1)),
                dec.domain_.pattern.shape.squared(physics), check.shape.squared(departure),
                relative_departure(departure, physics, check.floor_N),
                rel.sum(axis=2), loaded.sum(axis=2))


def pair_stats(index: int, n_train: int = 1000, n_test: int = 300) -> PairStats:
    """lm-mlp and deconv trained on ``random_pair(index)``'s training scene, measured."""
    pair: ScenePair = random_pair(index)
    data = pair_data(pair, n_train, n_test, 1)
    deconv = create_decoder("deconv").fit(*data.train)
    dec = create_decoder("lm-mlp").fit(*data.train)
    assert isinstance(dec, LMMLPDecoder)
    domain = dec.domain_
    pattern = domain.pattern
    assert pattern is not None
    check = domain.departure
    if check is None:  # a few long episodes: a check of its fitted rows, only to be scaled
        departure, physics, _ = _departure(dec, data.train[0])
        check = DepartureCheck.fit(departure, departure, physics,
                                   FLOOR_FRACTION * dec.constants.full_scale_force_N)
    dec.domain_ = dataclasses.replace(
        domain, pattern=dataclasses.replace(pattern, limit=LIFTED),
        departure=dataclasses.replace(check, patch_limit=LIFTED, taxel_limit=LIFTED))
    dec._prepare()
    return PairStats(index, f"{pair.mode}: {pair.train.label()} -> {pair.test.label()}",
                     domain.departure is None,
                     floored(data.away[1], deconv.decode(data.away[0]), pair.mode),
                     (pattern.limit, check.patch_limit, check.taxel_limit),
                     _side(dec, check, *data.home, pair.mode),
                     _side(dec, check, *data.away, pair.mode))


def _stream(side: Side, window: int) -> F64:
    """Per sample, the median over the last ``window`` samples of its mean relative departure
    over its loaded taxels."""
    taxel = np.where(np.isfinite(side.taxel), side.taxel, 10.0)
    loaded = taxel > 0
    mean = (taxel * loaded).sum(axis=1) / np.maximum(loaded.sum(axis=1), 1)
    return np.array([np.median(mean[max(0, t - window + 1):t + 1]) for t in range(mean.size)])


def as_fitted(stats: PairStats) -> tuple[float, float, float]:
    """The scale of the limits as lm-mlp fitted them (no departure check for episodes)."""
    return (1.0, np.inf, np.inf) if stats.episodes else (1.0, 1.0, 1.0)


def judge_scaled(stats: PairStats, scale: tuple[float, float, float],
                 window: int | None = None) -> dict[str, Any]:
    """Both halves of the promise with the three limits times ``scale`` (and the stream check
    of ``window`` samples, if given)."""
    out: dict[str, Any] = {}
    stream_limit = np.inf if window is None else float(_stream(stats.home, window).max())
    for name, side in (("home", stats.home), ("away", stats.away)):
        bad = ((side.pattern > scale[0] * stats.limits[0])[:, None]
               | (side.patch > scale[1] * stats.limits[1])[:, None]
               | (side.taxel > scale[2] * stats.limits[2]))
        if window is not None:
            bad |= (_stream(side, window) > stream_limit)[:, None]
        bad &= side.whole[:, None]
        valid = side.valid & ~bad
        count = int(side.err_count[valid].sum())
        out[f"flagged_{name}"] = float(np.mean(side.boxed | bad))
        out[f"error_{name}_pct"] = 100 * float(side.err_sum[valid].sum()) / count if count else None
    bar = bar_pct(stats.deconv_away_pct, out["error_home_pct"])
    err = out["error_away_pct"]
    out["home_met"] = out["flagged_home"] <= HOME_SHARE
    out["away_met"] = err is None or (bar is not None and err <= bar)
    out["bar_pct"] = bar
    return out


def _met(stats: PairStats, scale: tuple[float, float, float], window: int | None = None) -> bool:
    judged = judge_scaled(stats, scale, window)
    return bool(judged["home_met"] and judged["away_met"])


def settings() -> list[tuple[float, float, float]]:
    off = [*MULTIPLES, np.inf]
    return [(float(a), float(b), float(c)) for a, b, c in itertools.product(MULTIPLES, off, off)]


def reach(stats: list[PairStats], window: int | None = None) -> dict[str, Any]:
    """The pairs met as fitted, by the best common setting, and by any setting at all."""
    grid = settings()
    met = np.array([[_met(s, g) for g in grid] for s in stats])  # (pairs, settings)
    fitted = [_met(s, as_fitted(s)) for s in stats]
    best = int(np.argmax(met.sum(axis=0)))
    out: dict[str, Any] = {
        "pairs": len(stats), "met_as_fitted": int(sum(fitted)),
        "best_common": {"scale": grid[best], "met": int(met[:, best].sum())},
        "reachable": int(met.any(axis=1).sum()),
        "unreachable": [{"pair": s.index, "scene": s.label, "episodes": s.episodes}
                        for s, m in zip(stats, met, strict=True) if not m.any()]}
    if window is not None:
        with_stream = [_met(s, as_fitted(s), window) for s in stats]
        out["stream"] = {"window": window, "met": int(sum(with_stream)),
                         "missed": [s.index for s, m in zip(stats, with_stream, strict=True)
                                    if not m]}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=count("--pairs", 1, 100_000), default=120,
                        help="random_pair(0..N-1)")
    parser.add_argument("--jobs", type=count("--jobs", 1, 256), default=2)
    parser.add_argument("--window", type=count("--window", 1, 100_000), default=None)
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        stats = list(pool.map(pair_stats, range(args.pairs)))
    result = reach(stats, args.window)
    text = json.dumps(result, indent=2)
    print(text)  # first: a --json that cannot be written loses no result
    if args.json:
        try:
            with atomic_write(args.json) as out:
                out.write((text + "\n").encode())
        except OSError as err:
            print(f"limits_reach: error: {err}", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
