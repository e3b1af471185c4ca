"""``skin bench cross``: every decoder trained on one scene and tested on the others.

z-only: ``paper``, ``paper-noisy`` and ``indenter`` read through pillar z (their loads are
pure presses, which is what a z-only reading can decode). 3-axis: those three and
``slide`` and ``grasp`` (which shear the taxels, so they are read in 3-axis mode only).
Each cell: the share of taxels the decoder flags EXTRAPOLATED, its floored AveRelErr on
the taxels it does not flag, and the oracle's on the same taxels.
"""

from __future__ import annotations

from typing import Any

Z_SCENES = ("paper", "paper-noisy", "indenter")
XYZ_SCENES = ("paper", "paper-noisy", "indenter", "slide", "grasp")


def _scene(name: str, mode: str) -> Any:
    import sim

    data = sim.load_scene(name).to_dict()
    data["scene"]["mode"] = mode
    return sim.scene_from_dict(data)


def _untrained(names: tuple[str, ...]) -> list[str]:
    from decoder.protocol import BaseDecoder
    from decoder.registry import decoder_class

    out = []
    for name in names:
        cls = decoder_class(name)
        if isinstance(cls, type) and issubclass(cls, BaseDecoder) and not cls.needs_fitting:
            out.append(name)
    return out


def run_cross(quick: bool, params: dict[str, dict[str, Any]]) -> dict[str, Any]:
    import sim
    from bench import decoders as benchmark
    from decoder.registry import available_decoders

    n_train, n_test = (500, 200) if quick else (1000, 500)
    names = available_decoders()
    result: dict[str, Any] = {"train_samples": n_train, "test_samples": n_test,
                              "train_seed": 1, "test_seed": 2, "oracle": [], "cells": []}
    for mode, scenes in (("z", Z_SCENES), ("xyz", XYZ_SCENES)):
        train, test = {}, {}
        for name in scenes:
            scene = _scene(name, mode)
            a = sim.generate_dataset(scene, n_train, 1)
            b = sim.generate_dataset(scene, n_test, 2)
            train[name] = (a.resistance_ohm, a.force_N)
            test[name] = (b.resistance_ohm, b.force_N, scene.crosstalk_matrix())
        part = benchmark.cross_matrix(train, test, mode, names, params=params,
                                      untrained=_untrained(names))
        result["oracle"] += part["oracle"]
        result["cells"] += part["cells"]
    result["bars"] = benchmark.cross_bars(result["cells"])
    return result


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def print_cross(result: dict[str, Any]) -> None:
    from skin.commands.common.tables import show

    oracle = {(o["mode"], o["test"]): o for o in result["oracle"]}
    for mode, scenes in (("z", Z_SCENES), ("xyz", XYZ_SCENES)):
        title = (f"{'z-only' if mode == 'z' else '3-axis'}: floored AveRelErr % on the taxels "
                 "not flagged / the oracle's on the same taxels (share flagged EXTRAPOLATED)")
        caption = (f"{result['train_samples']} training, {result['test_samples']} test "
                   "samples per scene")
        table = [["oracle", "", *[_pct(oracle[mode, t]["ave_rel_err_floored_pct"])
                                  for t in scenes]]]
        rows: dict[tuple[str, str | None], dict[str, str]] = {}
        for c in result["cells"]:
            if c["mode"] != mode:
                continue
            text = (f"{_pct(c['ave_rel_err_floored_pct'])}/"
                    f"{_pct(c['oracle_same_taxels_floored_pct'])} "
                    f"{100 * c['flagged_share']:.0f}%")
            rows.setdefault((c["decoder"], c["train"]), {})[c["test"]] = text
        for (decoder, train), cells in rows.items():
            table.append([decoder, train or "(untrained)", *[cells.get(t, "") for t in scenes]])
        show(title, ["decoder", "trained on", *scenes], table, caption=caption, labels=2)
    bars = result["bars"]
    for key, label in (("hybrid_vs_deconv", "hybrid <= 1.2x deconv"),
                       ("unflagged_vs_oracle", "unflagged <= 2x the oracle")):
        checked = [b for b in bars[key] if b["met"] is not None]
        missed = [b for b in checked if not b["met"]]
        exact = len(bars[key]) - len(checked)
        print(f"{label} on unseen scenes: met in {len(checked) - len(missed)} of "
                      f"{len(checked)} cells" + (f" ({exact} more on a noise-free test set, "
                                                 "where the oracle is exact)" if exact else ""))
        for b in missed:
            who = b.get("decoder", "hybrid")
            print(f"  not met: {who} {b['mode']} {b['train']} -> {b['test']}: "
                          f"{_pct(b.get('error', b.get('hybrid')))} % against "
                          f"{_pct(b.get('oracle', b.get('deconv')))} %, ratio {_pct(b['ratio'])}"
                          + (f" on {b['compared']} components" if "compared" in b else ""))
