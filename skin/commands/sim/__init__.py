"""``skin sim``: simulated patches; ``skin sim dataset`` writes a dataset file."""

from __future__ import annotations

import argparse
import importlib
from typing import Any

from skin.commands.common import argtypes


def _dataset(args: argparse.Namespace) -> int:
    from sim import generate_dataset, load_scene
    from skin.dataset import write_dataset

    scene = load_scene(args.scene)
    seed = scene.seed if args.seed is None else args.seed
    ds = generate_dataset(scene, args.n, seed)
    write_dataset(args.output, ds)
    s, p, _, pillars = ds.resistance_ohm.shape
    print(f"wrote {args.output}: {s} samples x {p} patches x 9 taxels x {pillars} pillars "
          f"(scene {scene.name}, seed {seed})")
    return 0


def add_subparser(subparsers: Any) -> None:
    parser = subparsers.add_parser("sim", help="simulated patches: datasets, patches on a bus")
    group = parser.add_subparsers(title="sim commands", metavar="ACTION", required=True)
    dataset = group.add_parser("dataset", help="write a dataset (.npz) of a scene")
    dataset.add_argument("scene", metavar="SCENE", help="a shipped scene name or a .toml path")
    dataset.add_argument("-n", type=argtypes.count("samples", 1, 10**12), required=True,
                         metavar="N", help="number of samples")
    dataset.add_argument(
        "--seed", type=argtypes.seed, default=None, help="random seed (default: the scene's own)"
    )
    dataset.add_argument("-o", "--output", type=argtypes.output_file, required=True,
                         metavar="FILE", help="output .npz")
    dataset.set_defaults(func=_dataset)
    try:  # `skin sim run` lives in its own module
        sim_run = importlib.import_module("skin.commands.sim.run")
    except ModuleNotFoundError as err:
        if err.name != "skin.commands.sim.run":
            raise
    else:
        sim_run.add_subparser(group)
