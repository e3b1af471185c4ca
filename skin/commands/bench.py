"""``skin bench [decoders|cross|sim|dataplane|server]``: decoders' speed against error and the
paper's Table 1, decoders trained on one scene and tested on others, the simulator's speed, the
CAN data plane against canopen's PdoMap callbacks, or the patch server against python-can's own
send."""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from typing import Any

SCENES = ("paper", "paper-noisy")
"""The paper's protocol as published (noise-free), and the noise study (read noise, ADC)."""
TABLE1_SCENES = ("paper", "paper-noisy", "indenter")


def add_subparser(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "bench", help="speed against error of every decoder; the paper's Table 1; cross-scene",
        description="decoders: fit every registered decoder on `paper` (the paper's noise-free "
                    "protocol) and `paper-noisy` (the noise study) with 1000 training and 100 "
                    "test samples and several seeds, time it, sweep lm-mlp's hidden nodes "
                    "5..14 (the paper's Table 1) on `paper`, `paper-noisy` and `indenter`, "
                    "and choose the hidden layer by the paper's method (--hidden auto). "
                    "cross: every decoder trained on one scene and tested on the others. "
                    "sim: the simulator's speed. dataplane: 16 patches' TPDOs absorbed, "
                    "decoded and republished as force TPDOs, against the same work through "
                    "canopen's PdoMap callbacks. server: N simulated patches served on "
                    "udp_multicast to a master in another process, the server's CPU per "
                    "frame against python-can's own send of the same frames in the same run, "
                    "SYNC to the last TPDO, patches per core.")
    parser.add_argument("target", nargs="?",
                        choices=("decoders", "cross", "sim", "dataplane", "server"),
                        default="decoders")
    parser.add_argument("--quick", action="store_true",
                        help="one seed, smaller batches and sets (about a minute or less)")
    parser.add_argument("--goal-units", choices=("N", "scaled"), default="N",
                        help="where lm-mlp's and hybrid's goal MSE 1e-4 is measured: on the "
                             "forces in newtons (default; MATLAB's default performance "
                             "function) or on the mapminmax-scaled outputs")
    parser.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    parser.add_argument("--plot", metavar="FILE.png", help="draw speed against error")
    from skin.commands.bench_server import add_arguments

    add_arguments(parser)
    parser.set_defaults(func=run)


def _write_json(path: str, data: dict[str, Any]) -> None:
    from skin.atomic import atomic_write

    with atomic_write(path) as handle:
        handle.write(json.dumps(data, indent=2).encode() + b"\n")


def _splits(scene: str, seeds: int) -> list[tuple[Any, ...]]:
    import sim

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
    from decoder.metrics import evaluate
    from decoder.registry import create_decoder

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
    import sim
    from decoder import benchmark
    from decoder.registry import available_decoders, create_decoder

    seeds, batch, repeats = (1, 20_000, 2) if quick else (3, 200_000, 5)
    params = mlp_params(goal_units)
    result: dict[str, Any] = {"goal_units": goal_units, "seeds": seeds, "scenes": []}
    splits: dict[str, list[tuple[Any, ...]]] = {}
    for name in SCENES:
        stage(f"decoders on {name}")
        scene = sim.load_scene(name)
        splits[name] = _splits(name, seeds)
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
        scene_splits = splits.get(name) or _splits(name, seeds)
        table += benchmark.table1(scene_splits, sim.load_scene(name).mode, name,
                                  params=params["lm-mlp"])
    result["table1"] = table
    stage("--hidden auto")
    result["hidden_auto"] = hidden_auto(splits["paper"][0], "z", params["lm-mlp"])
    result["analytic_taxel_samples_per_s"] = {
        "z": benchmark.analytic_throughput(1, 10 * batch, repeats),
        "xyz": benchmark.analytic_throughput(3, 5 * batch, repeats)}
    stage("3-axis speed")
    r_xyz, f_xyz, r_xyz_test, _ = _splits("indenter", 1)[0]
    result["xyz_speed"] = [
        dict(zip(("name", "decode_samples_per_s", "latency_us"),
                 (name, *benchmark.decode_speed(
                     create_decoder(name, **params.get(name, {})).fit(r_xyz, f_xyz),
                     r_xyz_test, batch, repeats)), strict=True))
        for name in available_decoders()]
    stage("LM against SciPy")
    r_train, f_train = splits["paper"][0][0], splits["paper"][0][1]
    result["lm_vs_scipy"] = benchmark.lm_vs_scipy(
        r_train.reshape(r_train.shape[0], -1), f_train[..., 2].reshape(r_train.shape[0], -1),
        10, 10 if quick else 30)
    return result


def print_dataplane(result: dict[str, Any]) -> None:
    from skin.commands.tables import show

    rows = []
    for label, key in (("data plane", "dataplane"), ("data plane, batch 1", "per_patch"),
                       ("canopen PdoMaps", "canopen")):
        ratio = result["canopen_s"] / result[f"{key}_s"]
        rows.append([label, f"{result[f'{key}_frames_in_per_s']:,.0f}",
                     f"{result[f'{key}_frames_out_per_s']:,.0f}",
                     f"{100 * result[f'{key}_cpu_share']:.0f} %", f"{ratio:.2f}x"])
    show(f"data plane: {result['patches']} patches ({result['mode']}), "
         f"{result['frames_in']:,} PDOs in, {result['frames_out']:,} out",
         ["path", "frames in/s", "frames out/s", "CPU", "vs canopen"], rows,
         caption=f"{result['cycles']} SYNC cycles; best of {result['repeats']}; one thread; "
                 "python-can delivery excluded")
    print(f"identical force frames: {result['identical_output']}; all samples complete: "
                  f"{result['all_samples_complete']}")
    print(f"not included above: python-can virtual bus -> Notifier delivery alone "
                  f"{result['notifier_frames_per_s']:,.0f} frames/s; the whole path (virtual "
                  f"bus, Notifier, data plane thread) {result['pipeline_frames_per_s']:,.0f} "
                  f"frames/s, {result['pipeline_mean_batch']:.1f} samples per decode")


def limit_blas_threads() -> None:
    """LM's matrices are a few hundred wide: BLAS threads cost more than they give. SciPy
    may bring its own OpenBLAS, loaded on first import: import it before limiting, or its
    Cholesky keeps every core (10x slower per LM epoch on a busy 2-core machine)."""
    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api="blas")


def run(args: argparse.Namespace) -> int:
    limit_blas_threads()
    if args.target == "sim":
        from sim.benchmark import run_benchmark

        figures = run_benchmark(quick=args.quick)
        for key, value in figures.items():
            print(f"{key:<40} {value:>16,.3f}")
        if args.json:
            _write_json(args.json, dict(figures))
        return 0
    if args.target == "dataplane":
        from canbus.master.dataplane_bench import run_dataplane_benchmark

        cycles, repeats = (100, 2) if args.quick else (300, 5)
        figures = run_dataplane_benchmark(cycles=cycles, repeats=repeats)
        print_dataplane(figures)
        if args.json:
            _write_json(args.json, figures)
        return 0
    if args.target == "server":
        from skin.commands.bench_server import print_server, run_server

        result = run_server(args)
        print_server(result)
        if args.json:
            _write_json(args.json, result)
        return 0
    if args.target == "cross":
        from skin.commands.bench_cross import print_cross, run_cross

        result = run_cross(args.quick, mlp_params(args.goal_units))
        print_cross(result)
        if args.json:
            _write_json(args.json, result)
        return 0
    from skin.commands.bench_view import Stages, check_plot, plot, print_decoders, uncovered
    from skin.commands.eval import NO_RESULT

    if args.plot:
        check_plot(args.plot)  # before minutes of work, not after
    stages = Stages(len(SCENES) + len(TABLE1_SCENES) + 3)
    try:
        result = run_decoders(args.quick, args.goal_units, stages)
    finally:
        stages.close()
    print_decoders(result)
    if args.json:
        _write_json(args.json, result)
    if args.plot:
        plot(result, args.plot)
    return NO_RESULT if uncovered(result) else 0
