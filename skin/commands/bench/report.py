"""What ``skin bench`` prints for the decoders, and its speed-against-error chart."""

from __future__ import annotations

import math
from typing import Any

from skin.commands.common.tables import show
from skin.errors import ConfigError


def _f(value: float | None, digits: int = 3) -> str:
    return "-" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def uncovered(result: dict[str, Any]) -> list[str]:
    """The figures of a ``skin bench`` run that cover no taxel: ``lm-mlp on paper``.
    (Table 1 scores every test component, flagged or not, as the paper does: it always
    covers them all, and gives the share its checks flag beside.)"""
    return [f"{d['name']} on {part['scene']}" for part in result["scenes"]
            for d in part["decoders"] if not d["covered_pct"]]


def _scene_table(part: dict[str, Any], seeds: int) -> None:
    noise = "read noise and ADC" if part["noise"] else "noise-free"
    title = (f"decoders on '{part['scene']}' ({noise}, z-only; means over {seeds} "
             f"seed{'s' if seeds > 1 else ''})")
    speed = "latency_us" in part["decoders"][0] if part["decoders"] else False
    columns = ["decoder", "covers %", "AveRelErr %", "floored %", "x oracle", "RMSE %FS",
               "max rel floored %", "train s"]
    if speed:
        columns += ["patch-samples/s", "latency us", "flagged us"]
    o = part["oracle"]
    rows = [["oracle", _f(o["covered_pct"], 2), _f(o["ave_rel_err_pct"]),
             _f(o["ave_rel_err_floored_pct"]), "", _f(o["rmse_pct_fs"]),
             *[""] * (len(columns) - 6)]]
    for d in part["decoders"]:
        ratio = (d["ave_rel_err_pct"] / o["ave_rel_err_pct"]
                 if o["ave_rel_err_pct"] > 1e-6 else None)
        cells = [d["name"], _f(d["covered_pct"], 2), _f(d["ave_rel_err_pct"]),
                 _f(d["ave_rel_err_floored_pct"]), _f(ratio, 3), _f(d["rmse_pct_fs"]),
                 _f(d["max_rel_err_floored_pct"], 2), _f(d["train_s"])]
        if speed:
            cells += [f"{d['decode_samples_per_s']:,.0f}", f"{d['latency_us']:.1f}",
                      _f(d.get("latency_flagged_us"), 1)]
        rows.append(cells)
    show(title, columns, rows)
    print(f"best: {part['best']}")


def _table1(result: dict[str, Any]) -> None:
    scenes = list(dict.fromkeys(r["scene"] for r in result["table1"]))
    by = {(r["scene"], r["hidden"]): r for r in result["table1"]}
    pairs = result.get("table1_seed_pairs") or []
    title = (f"Table 1: lm-mlp AveRelErr % by hidden nodes (goal MSE 1e-4 in "
             f"{'N' if result['goal_units'] == 'N' else 'scaled units'}), median over "
             f"{len(pairs)} seed pairs")
    columns = ["hidden", "article"]
    for scene in scenes:
        columns.append(scene)
        if scene == "paper":
            columns += ["range", "seeds <= article"]
        columns.append(f"{scene} floored")
    rows = []
    for h in sorted({r["hidden"] for r in result["table1"]}):
        paper_ref = by[(scenes[0], h)]["paper_ave_rel_err_pct"]
        cells = [str(h), _f(paper_ref, 2)]
        for scene in scenes:
            row = by[(scene, h)]
            cells.append(_f(row["median_ave_rel_err_pct"]))
            if scene == "paper":
                cells.append(f"{row['min_ave_rel_err_pct']:.3g} .. "
                             f"{row['max_ave_rel_err_pct']:.3g}")
                count = row["seeds_at_most_paper"]
                cells.append("" if count is None else
                             f"{count} of {len(row['per_seed_ave_rel_err_pct'])}")
            cells.append(_f(row["median_ave_rel_err_floored_pct"]))
        rows.append(cells)
    show(title, columns, rows,
         caption="seed pairs " + ", ".join(f"{a}/{b}" for a, b in pairs)
         + "; every test component scored, as the paper scores it")


def print_decoders(result: dict[str, Any]) -> None:
    """The tables; every error beside the share of the taxels it covers ("covers %": of
    Table 1's, the least over its scenes). A figure that covers nothing is named first."""
    missing = uncovered(result)
    if missing:
        print(f"no result: every taxel masked for {', '.join(missing)}: those figures cover "
              "nothing")
    for part in result["scenes"]:
        _scene_table(part, result["seeds"])
    _table1(result)
    auto = result["hidden_auto"]
    curve = ", ".join(f"{c['hidden']}{'' if c['kept'] else ' (refused)'}: {c['val_mse']:.2e}"
                      for c in auto["curve"])
    print(f"lm-mlp --hidden auto on 'paper': Eq. 21 candidates "
                  f"{auto['candidates'][0]}..{auto['candidates'][-1]}, start {auto['start']}; "
                  f"validation MSE by size: {curve}; chose {auto['hidden']} "
                  f"({auto['stopped']}); AveRelErr {auto['ave_rel_err_pct']:.3f} %, floored "
                  f"{auto['ave_rel_err_floored_pct']:.3f} %")
    speed = result["analytic_taxel_samples_per_s"]
    lm = result["lm_vs_scipy"]
    show("3-axis decode speed ('indenter' scene, 27 pillars per patch)",
         ["decoder", "patch-samples/s", "latency us", "flagged us"],
         [[d["name"], f"{d['decode_samples_per_s']:,.0f}", f"{d['latency_us']:.1f}",
           _f(d.get("latency_flagged_us"), 1)]
          for d in result["xyz_speed"]])
    print(f"analytic: {speed['z']:,.0f} taxel-samples/s z-only, "
          f"{speed['xyz']:,.0f} 3-axis")
    print(f"LM vs SciPy least_squares(method='lm'), {lm['samples']} samples, "
                  f"{lm['params']} weights: ours {1e3 * lm['ours_s_per_iteration']:.2f} ms/it "
                  f"({lm['ours_nit']} it, MSE {lm['ours_mse']:.2e}, {lm['ours_s']:.3f} s), SciPy "
                  f"{1e3 * lm['scipy_s_per_iteration']:.1f} ms/it ({lm['scipy_njev']} it, MSE "
                  f"{lm['scipy_mse']:.2e}); {lm['speedup_per_iteration']:.0f}x per iteration")


def check_plot(path: str, flag: str = "--plot") -> None:
    """Refuse ``flag`` (``--plot``) before any work: matplotlib missing, or nowhere to write."""
    import os

    try:
        import matplotlib  # noqa: F401
    except ModuleNotFoundError as err:
        raise ConfigError(flag, "needs matplotlib: pip install 'canskin[plot]'") from err
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder) or not os.access(folder, os.W_OK):
        raise ConfigError(flag, f"cannot write in {folder!r}")
    if not path.lower().endswith(".png"):
        raise ConfigError(flag, f"writes a PNG: name it .png, got {path!r}")


class Stages:
    """A progress line on stderr through the long parts of a benchmark (a terminal only)."""

    def __init__(self, total: int) -> None:
        import sys

        self._progress: Any = None
        if sys.stderr.isatty():
            from rich.console import Console
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

            self._progress = Progress(TextColumn("{task.description}"), BarColumn(),
                                      TextColumn("{task.completed}/{task.total}"),
                                      TimeElapsedColumn(), console=Console(stderr=True),
                                      transient=True)
            self._task = self._progress.add_task("bench", total=total)
            self._progress.start()

    def __call__(self, label: str) -> None:
        if self._progress is not None:
            self._progress.update(self._task, description=f"bench: {label}", advance=1)

    def close(self) -> None:
        if self._progress is not None:
            self._progress.stop()


def plot(result: dict[str, Any], path: str) -> None:
    """Decode speed (on `paper`) against floored error on the noise study (`paper-noisy`)."""
    check_plot(path)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from skin.atomic import atomic_write

    speed = {d["name"]: d["decode_samples_per_s"] for d in result["decoders"]}
    noisy = next(p for p in result["scenes"] if p["scene"] == "paper-noisy")
    fig, ax = plt.subplots(figsize=(7, 4.5))
    placed: list[tuple[float, float]] = []
    for d in noisy["decoders"]:
        x, y = speed[d["name"]], d["ave_rel_err_floored_pct"]
        ax.scatter(x, y, s=40)
        # A point next to one already labelled (deconv and hybrid) gets its label below.
        near = any(abs(math.log(x / px)) < 0.1 and abs(math.log(y / py)) < 0.2
                   for px, py in placed)
        placed.append((x, y))
        ax.annotate(d["name"], (x, y), textcoords="offset points",
                    xytext=(5, -14 if near else 6))
    ax.axhline(noisy["oracle"]["ave_rel_err_floored_pct"], ls="--", c="grey", label="oracle")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("decode speed (patch-samples/s, batched)")
    ax.set_ylabel("AveRelErr, |F| >= 5 % FS (%), 'paper-noisy'")
    ax.set_title("speed against error (the noise study, 'paper-noisy')")
    ax.legend()
    fig.tight_layout()
    with atomic_write(path) as handle:
        fig.savefig(handle, format="png", dpi=120)
    plt.close(fig)
