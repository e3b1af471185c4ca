"""The promise of a trained decoder on one scene pair, measured.

At home (another seed of its training scene) it flags at most ``HOME_SHARE`` of the taxels;
away (the pair's test scene) its floored AveRelErr on the taxels it does not flag is at most
``FACTOR`` x the larger of deconv's on that pair and its own at home.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from decoder.metrics import evaluate
from decoder.protocol import Decoded, Decoder
from decoder.reasons import Reason
from decoder.registry import create_decoder
from skin.benchmarks.pairs import PairData, ScenePair, pair_data

HOME_SHARE = 0.05
FACTOR = 2.0
TRAINED = ("deconv", "lm-mlp", "hybrid")


def bar_pct(deconv_away_pct: float | None, home_pct: float | None) -> float | None:
    """The away bar: ``FACTOR`` x the larger of deconv's error away and the decoder's own at
    home (None when neither is known)."""
    known = [v for v in (deconv_away_pct, home_pct) if v is not None]
    return FACTOR * max(known) if known else None


def flagged_share(decoded: Decoded) -> float:
    return float(np.mean(decoded.reason == Reason.EXTRAPOLATED))


def floored(force_N: Any, decoded: Decoded, mode: str, valid: Any = None) -> float | None:
    """Floored AveRelErr (%) on the valid taxels (``valid`` or the decoder's own); None when
    no floored component is left."""
    report = evaluate(force_N, decoded.force_N, decoded.valid if valid is None else valid,
                      mode=mode)
    return float(report.ave_rel_err_floored_pct) if report.floored else None


def judge(name: str, decoder: Decoder, reference: Decoder, data: PairData,
          mode: str) -> dict[str, Any]:
    """One trained decoder on one pair, beside ``reference`` (deconv trained alike)."""
    home, away = decoder.decode(data.home[0]), decoder.decode(data.away[0])
    ref_away = reference.decode(data.away[0])
    own_home = floored(data.home[1], home, mode)
    own_away = floored(data.away[1], away, mode)
    compared = evaluate(data.away[1], away.force_N, away.valid, mode=mode).floored
    ref = floored(data.away[1], ref_away, mode)
    ref_same = floored(data.away[1], ref_away, mode, away.valid & ref_away.valid)
    bar = bar_pct(ref, own_home)
    return {"decoder": name, "flagged_home": flagged_share(home),
            "flagged_away": flagged_share(away), "error_home_pct": own_home,
            "error_away_pct": own_away, "deconv_away_pct": ref,
            "deconv_same_taxels_pct": ref_same, "bar_pct": bar, "compared": compared,
            "home_met": flagged_share(home) <= HOME_SHARE,
            "away_met": own_away is None or (bar is not None and own_away <= bar)}


def judge_pair(pair: ScenePair, *, n_train: int = 1000, n_test: int = 300, seed: int = 1,
               names: Sequence[str] = TRAINED,
               params: Mapping[str, Mapping[str, Any]] | None = None) -> dict[str, Any]:
    """Every decoder of ``names`` trained on the pair's training scene and judged."""
    data = pair_data(pair, n_train, n_test, seed)
    fitted: dict[str, Decoder] = {}
    rows = []
    for name in dict.fromkeys(("deconv", *names)):
        start = time.perf_counter()
        decoder = create_decoder(name, **dict((params or {}).get(name, {})))
        fitted[name] = decoder.fit(*data.train)
        row = judge(name, fitted[name], fitted.get("deconv", decoder), data, pair.mode)
        row["train_s"] = time.perf_counter() - start
        if name in names:
            rows.append(row)
    return {"pair": pair.name, "mode": pair.mode, "train": pair.train.label(),
            "test": pair.test.label(), "decoders": rows}
