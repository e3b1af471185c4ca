"""The runs behind ``skin bench decoders`` and ``skin bench cross``: the scenes' datasets
from the simulator, and every figure of :mod:`skin.benchmarks.decoders` measured on them."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import sim
from decoder.metrics import evaluate
from decoder.protocol import BaseDecoder
from decoder.registry import available_decoders, create_decoder, decoder_class
from decoder.speed import decode_speed, flagged_latency
from skin.benchmarks import decoders as benchmark

SCENES = ("paper", "paper-noisy")
"""The paper's protocol as published (noise-free), and the noise study (read noise, ADC)."""
TABLE1_SCENES = ("paper", "paper-noisy", "indenter")
TABLE1_SEEDS = 10
TABLE1_QUICK_SEEDS = 3
"""Table 1 over seed pairs 1/2, 3/4, ... 19/20 (``--quick``: 1/2, 3/4, 5/6)."""
Z_SCENES = ("paper", "paper-noisy", "indenter")
"""skin bench cross, z-only: pure presses, which is what a z-only reading can decode."""
XYZ_SCENES = ("paper", "paper-noisy", "indenter", "slide", "grasp")
"""skin bench cross, 3-axis: also the scenes that shear the taxels."""


def scene_splits(scene: str, seeds: int) -> list[tuple[Any, ...]]:
    """Per seed, 1000 training and 100 test samples of ``scene``: (r, F, r, F)."""
    out = []
    for s in range(seeds):
        train = sim.generate_dataset(scene, 1000, 2 * s + 1)
        test = sim.generate_dataset(scene, 100, 2 * s + 2)
        out.append((train.resistance_ohm, train.force_N, test.resistance_ohm, test.force_N))
    return out


def mlp_params(goal_units: str) -> dict[str, dict[str, Any]]:
    return {name: {"goal_units": goal_units} for name in ("lm-mlp", "hybrid")}


def hidden_auto(split: tuple[Any, ...], mode: str, params: dict[str, Any]) -> dict[str, Any]:
    """lm-mlp with --hidden auto on one split: the choice, its curve, its test error."""
    decoder = create_decoder("lm-mlp", **{**params, "hidden": "auto"})
    decoder.fit(split[0], split[1])
    decoded = decoder.decode(split[2])
    report = evaluate(split[3], decoded.force_N, decoded.valid, mode=mode)
    choice = getattr(decoder, "hidden_choice", None)
    assert choice is not None
    return {"hidden": choice.hidden, "candidates": list(choice.candidates),
            "start": choice.start, "stopped": choice.stopped,
            "curve": [{"hidden": st.hidden, "train_mse": st.train_mse, "val_mse": st.val_mse,
                       "epochs": st.epochs, "kept": st.kept} for st in choice.steps],
            "ave_rel_err_pct": report.ave_rel_err_pct,
            "ave_rel_err_floored_pct": report.ave_rel_err_floored_pct}


def run_decoders(quick: bool, goal_units: str = "N",
                 stage: Callable[[str], None] = lambda label: None) -> dict[str, Any]:
    """Every figure of ``skin bench``; ``stage(label)`` as each long part starts."""
    seeds, batch, repeats = (1, 20_000, 2) if quick else (3, 200_000, 5)
    table_seeds = TABLE1_QUICK_SEEDS if quick else TABLE1_SEEDS
    params = mlp_params(goal_units)
    result: dict[str, Any] = {"goal_units": goal_units, "seeds": seeds, "scenes": [],
                              "table1_seed_pairs": [[2 * s + 1, 2 * s + 2]
                                                    for s in range(table_seeds)]}
    splits: dict[str, list[tuple[Any, ...]]] = {}
    for name in SCENES:
        stage(f"decoders on {name}")
        scene = sim.load_scene(name)
        splits[name] = scene_splits(name, seeds)
        part = benchmark.bench_decoders(splits[name], scene.crosstalk_matrix(), scene.mode,
                                        available_decoders(), batch=batch, repeats=repeats,
                                        params=params, speed=name == "paper")
        result["scenes"].append({"scene": name, "mode": scene.mode,
                                 "noise": "noise" in scene.effects, **part})
    paper = result["scenes"][0]
    result.update(scene="paper", oracle=paper["oracle"], decoders=paper["decoders"])
    table = []
    for name in TABLE1_SCENES:
        stage(f"Table 1 on {name}")
        table += benchmark.table1(scene_splits(name, table_seeds), sim.load_scene(name).mode,
                                  name, params=params["lm-mlp"])
    result["table1"] = table
    stage("--hidden auto")
    result["hidden_auto"] = hidden_auto(splits["paper"][0], "z", params["lm-mlp"])
    result["analytic_taxel_samples_per_s"] = {
        "z": benchmark.analytic_throughput(1, 10 * batch, repeats),
        "xyz": benchmark.analytic_throughput(3, 5 * batch, repeats)}
    stage("3-axis speed")
    r_xyz, f_xyz, r_xyz_test, _ = scene_splits("indenter", 1)[0]
    result["xyz_speed"] = []
    for name in available_decoders():
        fitted = create_decoder(name, **params.get(name, {})).fit(r_xyz, f_xyz)
        rate, latency = decode_speed(fitted, r_xyz_test, batch, repeats)
        result["xyz_speed"].append({
            "name": name, "decode_samples_per_s": rate, "latency_us": latency,
            "latency_flagged_us": flagged_latency(fitted, r_xyz_test, repeats)})
    stage("LM against SciPy")
    r_train, f_train = splits["paper"][0][0], splits["paper"][0][1]
    result["lm_vs_scipy"] = benchmark.lm_vs_scipy(
        r_train.reshape(r_train.shape[0], -1), f_train[..., 2].reshape(r_train.shape[0], -1),
        10, 10 if quick else 30)
    return result


def _scene_read_as(name: str, mode: str) -> Any:
    data = sim.load_scene(name).to_dict()
    data["scene"]["mode"] = mode
    return sim.scene_from_dict(data)


def _untrained(names: tuple[str, ...]) -> list[str]:
    return [name for name in names if isinstance(cls := decoder_class(name), type)
            and issubclass(cls, BaseDecoder) and not cls.needs_fitting]


def run_cross(quick: bool, params: dict[str, dict[str, Any]], random: int = 0) -> dict[str, Any]:
    """Every decoder trained on one scene and tested on the others (``skin bench cross``)."""
    n_train, n_test = (500, 200) if quick else (1000, 500)
    names = available_decoders()
    result: dict[str, Any] = {"train_samples": n_train, "test_samples": n_test,
                              "train_seed": 1, "test_seed": 2, "oracle": [], "cells": []}
    for mode, scenes in (("z", Z_SCENES), ("xyz", XYZ_SCENES)):
        train, test = {}, {}
        for name in scenes:
            scene = _scene_read_as(name, mode)
            a = sim.generate_dataset(scene, n_train, 1)
            b = sim.generate_dataset(scene, n_test, 2)
            train[name] = (a.resistance_ohm, a.force_N)
            test[name] = (b.resistance_ohm, b.force_N, scene.crosstalk_matrix())
        part = benchmark.cross_matrix(train, test, mode, names, params=params,
                                      untrained=_untrained(names))
        result["oracle"] += part["oracle"]
        result["cells"] += part["cells"]
    result["bars"] = benchmark.cross_bars(result["cells"])
    from skin.benchmarks.cross import promise_rows, run_pairs, summary

    result["promise"] = promise_rows(result["cells"])
    result["pairs"] = run_pairs(quick, params, random)
    result["summary"] = summary([*result["promise"], *result["pairs"]["rows"]])
    return result
