"""``skin train DECODER --data FILE.npz -o MODEL.msgpack``: fit a decoder on a dataset."""

from __future__ import annotations

import argparse
import time
from typing import Any

from skin.commands.common import argtypes
from skin.errors import ConfigError


def hidden_nodes(text: str) -> int | str:
    """``--hidden``: a number of hidden nodes, or ``auto`` (the paper's Eq. 21 and pruning)."""
    if text == "auto":
        return text
    try:
        value = int(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected a number of nodes or 'auto', got {text!r}") \
            from err
    if not 1 <= value <= 1000:
        raise argparse.ArgumentTypeError(f"must be in 1..1000 or 'auto', got {value}")
    return value


def add_subparser(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "train", help="fit a decoder on a dataset and save the model",
        description="Fit DECODER (see `skin bench` for the list) on a dataset written by "
                    "`skin sim dataset` and save it as a msgpack model file. The model keeps "
                    "its training domain: a taxel outside it decodes as EXTRAPOLATED.")
    parser.add_argument("decoder", help="decoder name, e.g. analytic, deconv, lm-mlp, hybrid, "
                                        "eq9")
    parser.add_argument("--data", required=True, metavar="FILE.npz", help="training dataset")
    parser.add_argument("--hidden", type=hidden_nodes, metavar="N|auto",
                        help="hidden nodes (lm-mlp, hybrid); 'auto' chooses them the paper's "
                             "way: Eq. 21's candidates, then pruning from a wide layer")
    parser.add_argument("--goal-units", choices=("N", "scaled"),
                        help="where the goal MSE is measured (lm-mlp, hybrid): on the forces "
                             "in newtons (default, as MATLAB's trainlm) or on the scaled "
                             "outputs")
    parser.add_argument("--seed", type=argtypes.seed,
                        help="random seed of the weights and the split")
    parser.add_argument("-o", "--output", type=argtypes.output_file, required=True,
                        metavar="MODEL.msgpack")
    parser.set_defaults(func=run)


def _report(decoder: Any) -> list[str]:
    """What training says beyond the time: where it stopped, how the size was chosen."""
    lines = []
    result = getattr(decoder, "train_result", None)
    if result is not None:
        units = "N²" if getattr(decoder, "goal_units", "N") == "N" else "scaled outputs"
        lines.append(f"stopped: {result.message} after {result.nit} epochs; training MSE "
                     f"{result.mse:.3e}, validation MSE {result.val_mse:.3e} ({units}; goal "
                     f"{decoder.goal_mse:g})")
    choice = getattr(decoder, "hidden_choice", None)
    if choice is not None:
        lines += choice.describe()
    meta = decoder.meta() if hasattr(decoder, "meta") else {}
    crosstalk = meta.get("crosstalk")
    if crosstalk is not None:
        lines.append(f"crosstalk inverse: {crosstalk['model']} (kernel side "
                     f"{crosstalk['kernel_side']:.4f}, diagonal {crosstalk['kernel_diagonal']:.4f}"
                     f"; held-out MSE kernel {crosstalk['val_mse_kernel_N2']:.3e}, full "
                     f"{crosstalk['val_mse_full_N2']:.3e} N²)")
    domain = meta.get("domain")
    if domain is not None:
        lines.append(_domain_line(domain))
    residual = meta.get("residual")
    if residual is not None:
        used = int(residual["used"].sum())
        lines.append(f"residual network used on {used} of {residual['used'].size} outputs "
                     f"(those where it cut the held-out MSE by "
                     f"{100 * residual['required_gain']:.0f} % or more)")
        threshold = residual.get("threshold_N")
        if used and threshold is not None:
            import numpy as np

            median = float(np.median(threshold[residual["used"]]))
            lines.append(f"residual shrunk by {residual['threshold_standard_errors']:g} standard "
                         f"errors of its own fit: {1e3 * median:.2f} mN (median over the "
                         f"outputs used)")
    return lines


def _domain_line(domain: dict[str, Any]) -> str:
    """lm-mlp's checks of the whole patch, in one line (a warning where the departure check
    could not be calibrated)."""
    ratio = domain["exchangeable_ratio"]
    if domain["departure_check"] == "validation rows":
        return (f"domain: pattern and departure checks calibrated on held-out rows (held-out "
                f"blocks {ratio:.2f}x as unfamiliar as held-out rows; readings' box margin "
                f"{100 * domain['input_margin']:.0f} %)")
    return (f"domain: warning: held-out blocks of the training data are {ratio:.3g}x as "
            f"unfamiliar as held-out rows (a few long episodes): the departure check is off "
            f"and the pattern check alone decides; off this scene the network may be wrong "
            f"without a flag (train on more episodes, or use hybrid)")


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from decoder.registry import create_decoder
    from skin.commands.common.blas import limit_blas_threads
    from skin.dataset import read_training_set

    limit_blas_threads()
    dataset = read_training_set(args.data)
    given = (("hidden", args.hidden), ("seed", args.seed), ("goal_units", args.goal_units))
    params = {k: v for k, v in given if v is not None}
    try:
        decoder = create_decoder(args.decoder, **params)
    except TypeError as err:
        flags = "/".join(f"--{k.replace('_', '-')}" for k in params)
        raise ConfigError(flags, f"decoder {args.decoder!r} takes no such parameter "
                                 f"({err})") from err
    console = Console(stderr=True)
    auto = getattr(decoder, "hidden", None) == "auto"
    epochs = 0 if auto else int(getattr(decoder, "max_epochs", 0))
    columns = (TextColumn("[bold]{task.description}"), BarColumn(),
               TextColumn("epoch {task.completed:.0f}  {task.fields[status]}"),
               TimeElapsedColumn())
    start = time.perf_counter()
    with Progress(*columns, console=console, transient=True) as bar:
        task = bar.add_task(f"training {args.decoder}", total=epochs or None, status="")

        def progress(epoch: int, mse: float, mu: float) -> None:
            bar.update(task, completed=epoch, status=f"mse {mse:.3e}  mu {mu:.0e}")

        decoder.fit(dataset.resistance_ohm, dataset.force_N, progress=progress)
    elapsed = time.perf_counter() - start
    decoder.save(args.output)
    print(f"trained {args.decoder} on {dataset.resistance_ohm.shape[0]} samples "
          f"in {elapsed:.3f} s -> {args.output}")
    for line in _report(decoder):
        print(line)
    return 0
