"""``skin train DECODER --data FILE.npz -o MODEL.msgpack``: fit a decoder on a dataset."""

from __future__ import annotations

import argparse
import time
from typing import Any

from skin.errors import ConfigError


def add_subparser(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "train", help="fit a decoder on a dataset and save the model",
        description="Fit DECODER (see `skin bench` for the list) on a dataset written by "
                    "`skin sim dataset` and save it as a msgpack model file.")
    parser.add_argument("decoder", help="decoder name, e.g. analytic, deconv, lm-mlp, hybrid")
    parser.add_argument("--data", required=True, metavar="FILE.npz", help="training dataset")
    parser.add_argument("--hidden", type=int, help="hidden nodes (lm-mlp, hybrid)")
    parser.add_argument("--seed", type=int, help="random seed of the weights and the split")
    parser.add_argument("-o", "--output", required=True, metavar="MODEL.msgpack")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
    from threadpoolctl import threadpool_limits

    from decoder.registry import create_decoder
    from skin.dataset import read_dataset

    # LM's matrices are a few hundred wide: BLAS threads cost more than they give.
    threadpool_limits(1, user_api="blas")
    dataset = read_dataset(args.data)
    params = {k: v for k, v in (("hidden", args.hidden), ("seed", args.seed)) if v is not None}
    try:
        decoder = create_decoder(args.decoder, **params)
    except TypeError as err:
        raise ConfigError("--hidden/--seed", f"decoder {args.decoder!r} takes no such "
                          f"parameter ({err})") from err
    console = Console(stderr=True)
    epochs = int(getattr(decoder, "max_epochs", 0))
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
    result = getattr(decoder, "train_result", None)
    print(f"trained {args.decoder} on {dataset.resistance_ohm.shape[0]} samples "
          f"in {elapsed:.3f} s -> {args.output}")
    if result is not None:
        print(f"stopped: {result.message} after {result.nit} epochs; training MSE "
              f"{result.mse:.3e} (scaled outputs), validation MSE {result.val_mse:.3e}")
    return 0
