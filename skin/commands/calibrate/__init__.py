"""``skin calibrate D.npz -o MODEL.msgpack``: a patch's own decoder, chosen by k-fold
validation on its calibration data; ``skin calibrate --check MODEL D.npz``: does a model
still fit its patch (docs/calibrate.md).

Exit status of ``--check``: 0 the model fits; 3 it does not: recalibrate; 4 it fits once
the patch is tared again (its rest moved, the decoder still fits); 1 an error.
"""

from __future__ import annotations

import argparse
import math
import time
from typing import Any

from skin.commands.common import argtypes

FITS, RECALIBRATE, RETARE = 0, 3, 4
DEFAULT_TOLERANCE = 1.25
DEFAULT_SLACK_PCT = 0.1


def add_subparser(subparsers: Any) -> None:
    from skin.commands.train import hidden_nodes

    parser = subparsers.add_parser(
        "calibrate", help="fit a patch's own decoder from its calibration data, or check one",
        description="Fit each candidate decoder on a patch's dataset (skin dataset "
                    "from-recording, or skin sim dataset) with k-fold validation over "
                    "contiguous folds, choose the one with the lowest held-out floored "
                    "error (the faster of a tie), refit it on all the data and write the "
                    "model with its report. The patch's rest resistances come from the "
                    "samples at rest (the tare). --check MODEL D.npz says whether a model "
                    "still fits: exit 0 it fits, 3 recalibrate, 4 re-tare.")
    parser.add_argument("dataset", metavar="D.npz", help="the patch's dataset")
    parser.add_argument("-o", "--output", type=argtypes.output_file, metavar="MODEL.msgpack",
                        help="the model to write")
    parser.add_argument("--check", metavar="MODEL", help="check MODEL against D.npz instead")
    parser.add_argument("--node", type=argtypes.node_id, metavar="N",
                        help="the patch, when the dataset holds several")
    parser.add_argument("--decoders", nargs="+", metavar="NAME[:HIDDEN]",
                        help="candidates, a decoder's name or name:hidden nodes (lm-mlp:8, "
                             "hybrid:auto) (default: analytic and every registered decoder "
                             "that learns)")
    parser.add_argument("--folds", type=argtypes.count("folds", 2, 100), default=5, metavar="K",
                        help="k of the k-fold validation (default 5)")
    parser.add_argument("--hidden", type=hidden_nodes, metavar="N|auto",
                        help="hidden nodes of the network decoders (default: each one's own)")
    parser.add_argument("--seed", type=argtypes.seed, help="random seed of the network decoders")
    parser.add_argument("--tie", type=argtypes.fraction, default=0.02, metavar="F",
                        help="held-out errors within this fraction of the best tie; the "
                             "faster decoder wins (default 0.02)")
    parser.add_argument("--max-flagged", type=argtypes.fraction, default=0.005, metavar="F",
                        help="a candidate that refuses more of the held-out taxels is not "
                             "chosen (default 0.005)")
    parser.add_argument("--rest-N", type=argtypes.number("force", low=0.0, high=1e3, unit="N"),
                        default=0.01, metavar="N",
                        help="a sample is at rest when every taxel's reference force is at "
                             "most this (default 0.01 N)")
    parser.add_argument("--report", type=argtypes.output_file, metavar="R.json",
                        help="write the calibration report")
    parser.add_argument("--json", type=argtypes.output_file, metavar="FILE",
                        help="write the command's figures as JSON")
    parser.add_argument("--config-snippet", type=argtypes.output_file, metavar="F.toml",
                        help="write the host config's [[patches]] table for this patch")
    parser.add_argument("--tolerance", type=argtypes.number("tolerance", above=0.0, high=10**6),
                        default=DEFAULT_TOLERANCE, metavar="X",
                        help="--check: the model fits while its floored error is at most X "
                             "times its own held-out figure plus 0.1 points (default 1.25)")
    parser.add_argument("--write-node", action="store_true",
                        help="also write the rest values to the patch's 0x2002 by SDO (bus "
                             "flags below)")
    parser.add_argument("--store", action="store_true",
                        help="with --write-node: then save the patch's manufacturer "
                             "parameters (0x1010 sub 4 \"save\"), so the rest survives "
                             "power-off")
    parser.add_argument("--sdo-timeout", type=argtypes.seconds, default=1.0, metavar="S",
                        help="SDO response time-out for --write-node (default 1 s)")
    argtypes.add_bus_arguments(parser)
    parser.set_defaults(func=_run)


def _nodes(meta: dict[str, Any], patches: int) -> list[int]:
    """The dataset's patches' node-IDs (a recording's, a scene's, else 1..)."""
    if meta.get("node_ids"):
        return [int(n) for n in meta["node_ids"]]
    scene = meta.get("scene")
    if isinstance(scene, dict) and scene.get("patches"):
        return [int(p["node_id"]) for p in scene["patches"]]
    return list(range(1, patches + 1))


def _patch(args: argparse.Namespace, meta: dict[str, Any], patches: int,
           preferred: int | None = None) -> tuple[int, int]:
    """(node-ID, index in the dataset's patch axis)."""
    from skin.errors import ConfigError

    nodes = _nodes(meta, patches)
    want = args.node if args.node is not None else preferred
    if want is None:
        if patches != 1:
            raise ConfigError("--node", f"{args.dataset} holds patches "
                              f"{', '.join(map(str, nodes))}: name one")
        return nodes[0], 0
    if want not in nodes:
        raise ConfigError("--node", f"{args.dataset} holds no patch {want} (it holds "
                          f"{', '.join(map(str, nodes))})")
    return int(want), nodes.index(want)


def _run(args: argparse.Namespace) -> int:
    from skin.errors import ConfigError

    if args.check:
        if args.output or args.write_node:
            raise ConfigError("--check", "checks a model: -o and --write-node do not apply")
        return _check(args)
    if not args.output:
        raise ConfigError("-o", "give the model file to write (or --check MODEL)")
    if args.store and not args.write_node:
        raise ConfigError("--store", "saves what --write-node writes: give --write-node")
    if not (math.isfinite(args.rest_N) and args.rest_N >= 0):
        raise ConfigError("--rest-N", f"must be >= 0 N, got {args.rest_N}")
    return _fit(args)


def _fit(args: argparse.Namespace) -> int:
    from decoder.calibration import report
    from decoder.tare import nominal_r0, normalise, tare_at_rest
    from skin.commands.calibrate.output import model_meta, save_model, snippet, write_json
    from skin.commands.common.blas import limit_blas_threads
    from skin.constants import SensorConstants
    from skin.dataset import read_training_set
    from skin.errors import ConfigError

    started = time.perf_counter()
    limit_blas_threads()
    ds = read_training_set(args.dataset)
    node, k = _patch(args, ds.meta, ds.resistance_ohm.shape[1])
    constants = SensorConstants.from_dict(ds.meta["constants"])
    r, f = ds.resistance_ohm[:, k], ds.force_N[:, k]
    pillars = r.shape[-1]
    r0 = nominal_r0(constants, pillars)
    tare = tare_at_rest(r, f, args.rest_N)
    if tare is None and args.write_node:
        raise ConfigError("--write-node", f"{args.dataset} has fewer than 10 samples at rest "
                          f"(|F| <= {args.rest_N:g} N): no tare to write to the patch")
    rest = tare.rest_ohm if tare is not None else r0
    cal = _calibrate(args, normalise(r, rest, r0), f, constants)
    found = report(cal, None if tare is None else tare.rest_ohm,
                   0 if tare is None else tare.samples, args.rest_N,
                   None if tare is None else tare.noise_ohm)
    found.update(node_id=node, dataset=args.dataset, model=args.output)
    save_model(cal.decoder, args.output, model_meta(found, node_id=node, dataset=args.dataset))
    text = snippet(node, cal.mode, args.output, None if tare is None else tare.rest_ohm,
                   args.config_snippet, constants.nominal_resistance_ohm)
    written = _write_fit(args, found, cal, tare, node, r0, text)
    if args.json:
        write_json(args.json, {**found, "seconds": time.perf_counter() - started,
                               "written_to_node": written})
    return 0


def _calibrate(args: argparse.Namespace, x: Any, f: Any, constants: Any) -> Any:
    """``decoder.calibration.calibrate`` on the normalised resistances, its stages and
    epochs shown on a transient progress bar on stderr."""
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from decoder.calibration import calibrate

    columns = (TextColumn("[bold]{task.description}"), BarColumn(),
               TextColumn("{task.fields[status]}"), TimeElapsedColumn())
    with Progress(*columns, console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task("calibrating", total=1, status="")

        def stage(what: str, done: int, total: int) -> None:
            bar.update(task, description=what, completed=done, total=total, status="")

        def epochs(epoch: int, mse: float, mu: float) -> None:
            bar.update(task, status=f"epoch {epoch}  mse {mse:.3e}")

        return calibrate(x, f, constants, names=args.decoders, folds=args.folds,
                         hidden=args.hidden, seed=args.seed, tie=args.tie,
                         max_flagged=args.max_flagged, stage=stage, epochs=epochs)


def _write_fit(args: argparse.Namespace, found: dict[str, Any], cal: Any, tare: Any,
               node: int, r0: Any, text: str) -> int:
    """The config snippet, the summary, the rest written to the patch (how many values),
    the report."""
    from skin.commands.calibrate.output import write_json, write_rest_to_node

    if args.config_snippet:
        from skin.atomic import atomic_write

        with atomic_write(args.config_snippet) as handle:
            handle.write(text.encode())
    _print_fit(args, found, cal, tare, node, r0)
    written = 0
    if args.write_node and tare is not None:
        written = write_rest_to_node(args, node, tare.rest_ohm)
        print(f"wrote {written} rest values to patch {node}'s 0x2002 on {args.described}"
              f"{' and saved them (0x1010)' if args.store else ''}; an active host reads "
              "them when it next configures the patch")
    if not args.config_snippet:
        print(text, end="")
    if args.report:
        write_json(args.report, found)
    return written


def _print_fit(args: argparse.Namespace, found: dict[str, Any], cal: Any, tare: Any,
               node: int, r0: Any) -> None:
    import numpy as np

    mode = "3-axis" if cal.mode == "xyz" else "z-only"
    print(f"calibrated patch {node} on {cal.samples} samples of {args.dataset} ({mode}), "
          f"{cal.folds} contiguous folds")
    if tare is None:
        print(f"no tare: fewer than 10 samples at rest (|F| <= {args.rest_N:g} N); the model "
              "assumes the patch reports its true R0")
    else:
        ratio = tare.rest_ohm / r0
        print(f"tare: {tare.samples} samples at rest (|F| <= {args.rest_N:g} N): R0 "
              f"{np.min(ratio):.4f}..{np.max(ratio):.4f} x nominal, read noise "
              f"{np.mean(tare.noise_ohm):.3f} ohm")
    print(f"{'candidate':<10} {'held-out floored %':>18} {'AveRelErr %':>12} {'RMSE N':>8} "
          f"{'refused %':>9} {'fit s':>7} {'us/sample':>9}")
    for c in found["candidates"]:
        mark = "" if c["eligible"] else f"  (not chosen: {c['why_not']})"
        print(f"{c['decoder']:<10} {_fmt(c['heldout_floored_pct']):>18} "
              f"{_fmt(c['heldout_ave_rel_err_pct']):>12} {_fmt(c['rmse_N'], 4):>8} "
              f"{c['flagged_pct']:>9.2f} {c['fit_s']:>7.2f} {_fmt(c['latency_us'], 1):>9}{mark}")
    hidden = f" ({found['hidden']} hidden)" if found["hidden"] else ""
    print(f"chose {found['decoder']}{hidden}: held-out floored {found['heldout_floored_pct']:.3f} "
          f"%, {found['speed']['x_analytic']:.1f}x analytic per patch-sample -> {args.output}")


def _fmt(value: float | None, digits: int = 3) -> str:
    return "-" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _check(args: argparse.Namespace) -> int:
    from decoder.calibration import check_calibration_meta
    from decoder.modelfile import read_model
    from decoder.protocol import BaseDecoder
    from decoder.registry import load_decoder
    from decoder.tare import nominal_r0, normalise, tare_at_rest
    from skin.commands.calibrate.output import write_json
    from skin.constants import DEFAULT_CONSTANTS
    from skin.dataset import read_dataset
    from skin.errors import ConfigError

    if not (math.isfinite(args.tolerance) and args.tolerance >= 1):
        raise ConfigError("--tolerance", f"must be >= 1, got {args.tolerance}")
    own = check_calibration_meta(read_model(args.check).meta.get("calibration"), args.check)
    model = load_decoder(args.check)
    ds = read_dataset(args.dataset)
    node, k = _patch(args, ds.meta, ds.resistance_ohm.shape[1], own.get("node_id"))
    r, f = ds.resistance_ohm[:, k], ds.force_N[:, k]
    pillars = r.shape[-1]
    mode = "z" if pillars == 1 else "xyz"
    if mode != own.get("mode"):
        raise ConfigError("--check", f"{args.check} reads {own.get('mode')} patches; "
                          f"{args.dataset} is {mode}")
    constants = model.constants if isinstance(model, BaseDecoder) else DEFAULT_CONSTANTS
    r0 = nominal_r0(constants, pillars)
    rest = own["tare"]["rest_ohm"] if own.get("tare", {}).get("rest_ohm") is not None else r0
    limit = own["heldout_floored_pct"] * args.tolerance + DEFAULT_SLACK_PCT

    def figures(rest_ohm: Any) -> dict[str, Any]:
        out = model.decode(normalise(r, rest_ohm, r0))
        return _check_figures(f, out, mode, constants, limit, own.get("flagged_pct", 0.0))

    now = figures(rest)
    tare = tare_at_rest(r, f, own.get("tare", {}).get("rest_N", 0.01))
    retared = figures(tare.rest_ohm) if tare is not None else None
    if now["fits"]:
        verdict, code = "fits", FITS
    elif retared is not None and retared["fits"]:
        verdict, code = "fits after a tare: re-tare the patch", RETARE
    else:
        verdict, code = "does not fit: recalibrate", RECALIBRATE
    own_pct = own["heldout_floored_pct"]
    where = f"patch {node} of {args.dataset} ({r.shape[0]} samples)"
    if now["flagged_pct"] >= 100.0:
        print(f"{args.check} refused every taxel of {where}: no result, its error covers "
              f"nothing (its own held-out {own_pct:.3f} %, limit {limit:.3f} %)")
    else:
        print(f"{args.check} on {where}: floored {_fmt(now['floored_pct'])} % over "
              f"{100 - now['flagged_pct']:.2f} % of the taxels (its own held-out "
              f"{own_pct:.3f} %, limit {limit:.3f} %), refused {now['flagged_pct']:.2f} %")
    if retared is not None and tare is not None:
        _print_retared(tare, rest, retared)
    print(f"{args.check} {verdict}")
    if args.json:
        write_json(args.json, {"model": args.check, "dataset": args.dataset, "node_id": node,
                               "own_heldout_floored_pct": own_pct, "limit_pct": limit,
                               "tolerance": args.tolerance, "now": now, "after_tare": retared,
                               "verdict": verdict, "exit_status": code})
    return code


def _check_figures(f: Any, decoded: Any, mode: str, constants: Any, limit: float,
                   own_flagged_pct: float) -> dict[str, Any]:
    """How the model decodes the dataset, and whether that fits its own calibration: the
    floored error within ``limit`` and no more than twice its own refusals (1 % at least)."""
    from decoder.metrics import evaluate

    e = evaluate(f, decoded.force_N, decoded.valid, mode=mode, constants=constants)
    flagged = float(1.0 - decoded.valid.mean())
    floored = e.ave_rel_err_floored_pct  # NaN when nothing was compared: never fits
    fits = floored <= limit and 100 * flagged <= max(1.0, 2 * own_flagged_pct)
    return {"floored_pct": floored, "ave_rel_err_pct": e.ave_rel_err_pct,
            "rmse_N": e.rmse_N, "flagged_pct": 100 * flagged,
            "covered_pct": 100 * e.covered_share, "fits": bool(fits)}


def _print_retared(tare: Any, rest: Any, retared: dict[str, Any]) -> None:
    import numpy as np

    drift = 100.0 * (np.asarray(tare.rest_ohm) / np.asarray(rest) - 1.0)
    print(f"after a tare on its {tare.samples} samples at rest (rest moved "
          f"{np.min(drift):+.3f}..{np.max(drift):+.3f} %): floored "
          f"{_fmt(retared['floored_pct'])} % over {100 - retared['flagged_pct']:.2f} % of the "
          f"taxels, refused {retared['flagged_pct']:.2f} %")
