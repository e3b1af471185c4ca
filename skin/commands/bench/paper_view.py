"""What ``skin bench paper`` prints, and its three-panel picture of Figures 8, 9 and 10."""

from __future__ import annotations

from typing import Any

from decoder.metrics import EDGE_TAXELS
from skin.benchmarks.paper import CLAIMS, GOAL_MSE, KEYS


def _num(value: Any, digits: int = 3) -> str:
    if value is None:
        return "-"
    if isinstance(value, int):
        return str(value)
    return f"{value:.{digits}g}"


def _met(key: str, value: Any) -> str:
    """Whether our figure says what the paper's does."""
    if value is None:
        return "no"
    if key == "iterations_to_goal":
        return "yes" if value <= 121 else "no"
    if key == "max_rel_err_pct":
        return "yes" if value <= 9.0 else "no"
    if key == "share_below_1pct":
        return "yes" if value > 0.5 else "no"
    if key == "median_rel_err_pct":
        return "yes" if value < 1.0 else "no"
    return "yes" if value > 1.0 else "no"


def print_paper(result: dict[str, Any]) -> None:
    from skin.commands.common.tables import show

    first = result["runs"][0]
    over = result["over_seeds"]
    pairs = ", ".join(f"{a}/{b}" for a, b in result["seed_pairs"])
    rows = []
    for key in KEYS:
        o = over[key]
        spread = f"{_num(o['min'])} .. {_num(o['max'])}" if len(result["runs"]) > 1 else ""
        rows.append([key, CLAIMS[key], _num(result[key]), _met(key, result[key]),
                     _num(o["median"]), spread])
    show(f"the paper's Figures 8-10 against ours ('paper', lm-mlp {first['hidden']} hidden, "
         f"goal MSE {GOAL_MSE:g} in {first['goal_units']})",
         ["figure", "paper", f"ours ({first['train_seed']}/{first['test_seed']})", "as paper",
          "median", "range"], rows,
         caption=f"Fig. 9-10 figures over the 10 shown test samples (90 Fz); seed pairs {pairs}")
    a = first["all"]
    print(f"all 100 test samples of seed pair {first['train_seed']}/{first['test_seed']} "
          f"(900 Fz): max {a['max_rel_err_pct']:.3g} % (floored {a['max_rel_err_floored_pct']:.3g}"
          f" %), median {a['median_rel_err_pct']:.3g} %, {100 * a['share_below_1pct']:.0f} % "
          f"below 1 %, edge/centre RMS {_num(a['edge_vs_centre_rmse'])}; the domain checks "
          f"would flag {100 * first['flagged_share']:.1f} % of the taxels; training stopped: "
          f"{first['stopped']} after {first['epochs']} iterations")


def plot_paper(result: dict[str, Any], path: str) -> None:
    """Fig. 8 (MSE per iteration), Fig. 9 (decoded against actual Fz) and Fig. 10 (relative
    error per component, edge taxels marked) of the first seed pair, one PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from skin.atomic import atomic_write

    run = result["runs"][0]
    fig, (ax8, ax9, ax10) = plt.subplots(1, 3, figsize=(15, 4.2))
    curve = np.asarray(run["mse_curve"])
    ax8.semilogy(np.arange(1, curve.size + 1), curve, label="ours, training MSE")
    ax8.axhline(GOAL_MSE, ls="--", c="grey", label="goal 1e-4")
    ax8.axvline(121, ls=":", c="tab:red", label="paper: goal at 121")
    ax8.set_xlabel("iteration")
    ax8.set_ylabel(f"MSE ({'N²' if run['goal_units'] == 'N' else 'scaled'})")
    ax8.set_title(f"Fig. 8: goal met at iteration {_num(run['iterations_to_goal'])}")
    ax8.legend()
    index = np.arange(1, len(run["shown_true_N"]) + 1)
    true, decoded = np.asarray(run["shown_true_N"]), np.asarray(run["shown_decoded_N"])
    ax9.plot(index, true, ".", c="tab:red", label="actual")
    ax9.plot(index, decoded, "o", mfc="none", c="tab:blue", label="decoded")
    ax9.set_xlabel("force component (10 samples x 9 taxels)")
    ax9.set_ylabel("Fz (N)")
    ax9.set_title("Fig. 9: decoding results")
    ax9.legend()
    rel = 100.0 * np.abs(decoded - true) / np.abs(true)
    edge = np.isin((index - 1) % 9, EDGE_TAXELS)
    ax10.semilogy(index[edge], rel[edge], "o", c="tab:orange", label="edge taxels")
    ax10.semilogy(index[~edge], rel[~edge], "s", c="tab:green", label="centre taxel")
    for level, text in ((9.0, "paper: max 9 %"), (1.0, "paper: most below 1 %")):
        ax10.axhline(level, ls="--", c="grey")
        ax10.annotate(text, (1, level), textcoords="offset points", xytext=(2, 3), fontsize=8)
    ax10.set_xlabel("force component")
    ax10.set_ylabel("relative error (%)")
    ax10.set_title(f"Fig. 10: max {rel.max():.3g} %, {100 * np.mean(rel < 1):.0f} % below 1 %")
    ax10.legend()
    fig.tight_layout()
    with atomic_write(path) as handle:
        fig.savefig(handle, format="png", dpi=110)
    plt.close(fig)


def run_command(quick: bool, goal_units: str, json_path: str | None,
                png_path: str | None) -> dict[str, Any]:
    """``skin bench paper``: seed pairs 1..10 (``quick``: 1/2 only), printed, and written."""
    from skin.benchmarks.paper import run_paper

    if png_path:
        from skin.commands.bench.report import check_plot

        check_plot(png_path, "--png")  # before the work, not after
    result = run_paper(range(1, 2 if quick else 11), goal_units=goal_units)
    print_paper(result)
    if png_path:
        plot_paper(result, png_path)
    return result
