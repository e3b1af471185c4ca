"""``skin bench cross``: every decoder trained on one scene and tested on the others.

z-only: ``paper``, ``paper-noisy`` and ``indenter`` read through pillar z (their loads are
pure presses, which is what a z-only reading can decode). 3-axis: those three and
``slide`` and ``grasp`` (which shear the taxels, so they are read in 3-axis mode only).
Each cell: the share of taxels the decoder flags EXTRAPOLATED, its floored AveRelErr on
the taxels it does not flag, and the oracle's on the same taxels. Then the promise pair by
pair (:mod:`bench.cross`): on those scenes and on the scene pairs of :mod:`bench.pairs`
(and ``--random N`` drawn ones), the share flagged at home and away and the unflagged error
against 2x the larger of deconv's on the pair and the decoder's own at home.
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
        if isinstance(cls, type) and issubclass(cls, BaseDecoder) and not cls._state:
            out.append(name)
    return out


def run_cross(quick: bool, params: dict[str, dict[str, Any]], random: int = 0) -> dict[str, Any]:
    import sim
    from decoder import benchmark
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
    from bench.cross import promise_rows, run_pairs, summary

    result["promise"] = promise_rows(result["cells"])
    result["pairs"] = run_pairs(quick, params, random)
    result["summary"] = summary([*result["promise"], *result["pairs"]["rows"]])
    return result


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def print_cross(result: dict[str, Any]) -> None:
    from skin.commands.tables import show

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
    checked = [b for b in bars["hybrid_vs_deconv"] if b["met"] is not None]
    missed = [b for b in checked if not b["met"]]
    print(f"hybrid <= 1.2x deconv on unseen scenes: met in {len(checked) - len(missed)} of "
          f"{len(checked)} cells")
    for b in missed:
        print(f"  not met: hybrid {b['mode']} {b['train']} -> {b['test']}: "
              f"{_pct(b['hybrid'])} % against {_pct(b['deconv'])} %, ratio {_pct(b['ratio'])}")
    from bench.cross_view import print_promise

    print_promise(result)
