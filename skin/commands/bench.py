"""``skin bench [decoders|sim|dataplane]``: decoders' speed against error, the simulator's speed,
or the CAN data plane against canopen's PdoMap callbacks."""

from __future__ import annotations

import argparse
import json
from typing import Any

from skin.errors import ConfigError

PAPER_TABLE1 = {5: 3.07, 6: 2.95, 7: 2.63, 8: 2.19, 9: 1.96, 10: 1.72, 11: 1.83, 12: 1.98,
                13: 2.17, 14: 2.06}
"""AveRelErr (%) of the paper's Table 1 by hidden nodes."""


def add_subparser(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "bench", help="speed against error of every decoder; the paper's Table 1",
        description="decoders: fit every registered decoder on the `paper` scene (1000 "
                    "training, 100 test samples, several seeds), time it, and sweep lm-mlp's "
                    "hidden nodes 5..14 on `paper` and `indenter`. sim: the simulator's speed. "
                    "dataplane: 16 patches' TPDOs absorbed, decoded and republished as force "
                    "TPDOs, against the same work through canopen's PdoMap callbacks.")
    parser.add_argument("target", nargs="?", choices=("decoders", "sim", "dataplane"),
                        default="decoders")
    parser.add_argument("--quick", action="store_true", help="one seed, smaller batches (<60 s)")
    parser.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    parser.add_argument("--plot", metavar="FILE.png", help="draw speed against error")
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


def run_decoders(quick: bool) -> dict[str, Any]:
    import sim
    from decoder import benchmark
    from decoder.registry import available_decoders, create_decoder

    seeds, batch, repeats = (1, 20_000, 2) if quick else (3, 200_000, 5)
    paper = sim.load_scene("paper")
    splits = _splits("paper", seeds)
    result: dict[str, Any] = {"scene": "paper"}
    result.update(benchmark.bench_decoders(splits, paper.crosstalk_matrix(), paper.mode,
                                           available_decoders(), batch=batch, repeats=repeats))
    table = benchmark.table1(splits, paper.mode, "paper")
    indenter = sim.load_scene("indenter")
    table += benchmark.table1(_splits("indenter", seeds), indenter.mode, "indenter")
    for row in table:
        row["paper_ave_rel_err_pct"] = PAPER_TABLE1[row["hidden"]]
    result["table1"] = table
    result["analytic_taxel_samples_per_s"] = {
        "z": benchmark.analytic_throughput(1, 10 * batch, repeats),
        "xyz": benchmark.analytic_throughput(3, 5 * batch, repeats)}
    r_xyz, f_xyz, r_xyz_test, _ = _splits("indenter", 1)[0]
    result["xyz_speed"] = [
        dict(zip(("name", "decode_samples_per_s", "latency_us"),
                 (name, *benchmark.decode_speed(create_decoder(name).fit(r_xyz, f_xyz),
                                                r_xyz_test, batch, repeats)), strict=True))
        for name in available_decoders()]
    r_train, f_train = splits[0][0], splits[0][1]
    result["lm_vs_scipy"] = benchmark.lm_vs_scipy(
        r_train.reshape(r_train.shape[0], -1), f_train[..., 2].reshape(r_train.shape[0], -1),
        10, 10 if quick else 30)
    return result


def print_decoders(result: dict[str, Any]) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console()
    table = Table(title=f"decoders on '{result['scene']}' (z-only; means over seeds)")
    for col in ("decoder", "AveRelErr %", "floored %", "RMSE %FS", "max rel floored %",
                "train s", "patch-samples/s", "latency us"):
        table.add_column(col, justify="left" if col == "decoder" else "right")
    o = result["oracle"]
    table.add_row("oracle", f"{o['ave_rel_err_pct']:.3f}", f"{o['ave_rel_err_floored_pct']:.3f}",
                  f"{o['rmse_pct_fs']:.3f}", "", "", "", "")
    for d in result["decoders"]:
        table.add_row(d["name"], f"{d['ave_rel_err_pct']:.3f}",
                      f"{d['ave_rel_err_floored_pct']:.3f}", f"{d['rmse_pct_fs']:.3f}",
                      f"{d['max_rel_err_floored_pct']:.2f}", f"{d['train_s']:.3f}",
                      f"{d['decode_samples_per_s']:,.0f}", f"{d['latency_us']:.1f}")
    console.print(table)
    t1 = Table(title="Table 1: lm-mlp AveRelErr % by hidden nodes")
    for col in ("hidden", "article", "paper", "paper floored", "indenter", "indenter floored"):
        t1.add_column(col, justify="right")
    by = {(r["scene"], r["hidden"]): r for r in result["table1"]}
    for h, ref in PAPER_TABLE1.items():
        cells = [f"{by[(s, h)][k]:.3f}" for s in ("paper", "indenter")
                 for k in ("ave_rel_err_pct", "ave_rel_err_floored_pct")]
        t1.add_row(str(h), f"{ref:.2f}", *cells)
    console.print(t1)
    speed = result["analytic_taxel_samples_per_s"]
    lm = result["lm_vs_scipy"]
    xyz = Table(title="3-axis decode speed ('indenter' scene, 27 pillars per patch)")
    for col in ("decoder", "patch-samples/s", "latency us"):
        xyz.add_column(col, justify="left" if col == "decoder" else "right")
    for d in result["xyz_speed"]:
        xyz.add_row(d["name"], f"{d['decode_samples_per_s']:,.0f}", f"{d['latency_us']:.1f}")
    console.print(xyz)
    console.print(f"analytic: {speed['z']:,.0f} taxel-samples/s z-only, "
                  f"{speed['xyz']:,.0f} 3-axis")
    console.print(f"LM vs SciPy least_squares(method='lm'), {lm['samples']} samples, "
                  f"{lm['params']} weights: ours {1e3 * lm['ours_s_per_iteration']:.2f} ms/it "
                  f"({lm['ours_nit']} it, MSE {lm['ours_mse']:.2e}, {lm['ours_s']:.3f} s), SciPy "
                  f"{1e3 * lm['scipy_s_per_iteration']:.1f} ms/it ({lm['scipy_njev']} it, MSE "
                  f"{lm['scipy_mse']:.2e}); {lm['speedup_per_iteration']:.0f}x per iteration")


def plot(result: dict[str, Any], path: str) -> None:
    try:
        import matplotlib
    except ModuleNotFoundError as err:
        raise ConfigError("--plot", "needs matplotlib: pip install 'canskin[plot]'") from err
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from skin.atomic import atomic_write

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for d in result["decoders"]:
        ax.scatter(d["decode_samples_per_s"], d["ave_rel_err_floored_pct"], s=40)
        ax.annotate(d["name"], (d["decode_samples_per_s"], d["ave_rel_err_floored_pct"]),
                    textcoords="offset points", xytext=(5, 5))
    ax.axhline(result["oracle"]["ave_rel_err_floored_pct"], ls="--", c="grey", label="oracle")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("decode speed (patch-samples/s, batched)")
    ax.set_ylabel("AveRelErr, |F| >= 5 % FS (%)")
    ax.set_title(f"speed against error, '{result['scene']}' scene")
    ax.legend()
    fig.tight_layout()
    with atomic_write(path) as handle:
        fig.savefig(handle, format="png", dpi=120)
    plt.close(fig)


def print_dataplane(result: dict[str, Any]) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console()
    table = Table(title=f"data plane: {result['patches']} patches ({result['mode']}), "
                        f"{result['frames_in']:,} PDOs in, {result['frames_out']:,} out",
                  caption=f"{result['cycles']} SYNC cycles; best of {result['repeats']}; "
                          "one thread; python-can delivery excluded")
    for col in ("path", "frames in/s", "frames out/s", "CPU", "vs canopen"):
        table.add_column(col, justify="left" if col == "path" else "right")
    rows = (("data plane", "dataplane"), ("data plane, batch 1", "per_patch"),
            ("canopen PdoMaps", "canopen"))
    for label, key in rows:
        ratio = result["canopen_s"] / result[f"{key}_s"]
        table.add_row(label, f"{result[f'{key}_frames_in_per_s']:,.0f}",
                      f"{result[f'{key}_frames_out_per_s']:,.0f}",
                      f"{100 * result[f'{key}_cpu_share']:.0f} %", f"{ratio:.2f}x")
    console.print(table)
    console.print(f"identical force frames: {result['identical_output']}; all samples complete: "
                  f"{result['all_samples_complete']}")
    console.print(f"not included above: python-can virtual bus -> Notifier delivery alone "
                  f"{result['notifier_frames_per_s']:,.0f} frames/s; the whole path (virtual "
                  f"bus, Notifier, data plane thread) {result['pipeline_frames_per_s']:,.0f} "
                  f"frames/s, {result['pipeline_mean_batch']:.1f} samples per decode")


def run(args: argparse.Namespace) -> int:
    from threadpoolctl import threadpool_limits

    # LM's matrices are a few hundred wide: BLAS threads cost more than they give.
    threadpool_limits(1, user_api="blas")
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
    result = run_decoders(args.quick)
    print_decoders(result)
    if args.json:
        _write_json(args.json, result)
    if args.plot:
        plot(result, args.plot)
    return 0
