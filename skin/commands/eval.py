"""``skin eval MODEL D.npz``: a decoder's error on a held-out dataset.

MODEL is a model file (``skin train``'s msgpack) or the name of a registered decoder that
needs no training (``analytic``). D.npz is a dataset of ``skin sim dataset``, best one the
model was not trained on (another seed). The figures are ``decoder.metrics``': the paper's
AveRelErr (Eq. 22), the floored one (|F| >= 5 % of full scale), RMSE in N and in % of full
scale, per axis, max absolute error, edge against centre taxels, over the taxels the
decoder did not mask, with the share of the taxels they cover in the first line; and the
share of taxels masked, by reason (every code a decoder returns, named by
``decoder.reasons.reason_name``). A run whose every taxel is masked has no result: its
first line says so and the command exits with 3.
"""

from __future__ import annotations

import argparse
import json
import math
import os
from typing import TYPE_CHECKING, Any

from skin.commands.common import argtypes

if TYPE_CHECKING:
    from decoder.protocol import Decoded, Decoder
    from skin.dataset import Dataset

_MODE_NAMES = {1: "z-only", 3: "3-axis"}
NO_RESULT = 3
"""Exit status when the figures cover no taxel (every one masked): no result."""


def add_subparser(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "eval", help="a decoder's error on a held-out dataset",
        description="Decode a dataset with MODEL (a model file from `skin train`, or the name "
                    "of a decoder that needs no training, e.g. analytic) and compare with its "
                    "true forces: AveRelErr (Eq. 22) plain and floored, RMSE (N, %% of full "
                    "scale, per axis), max error, edge against centre taxels, and the share "
                    "of taxels masked invalid by reason.")
    parser.add_argument("model", metavar="MODEL", help="a .msgpack model file or a decoder name")
    parser.add_argument("data", metavar="D.npz", help="the dataset (skin sim dataset)")
    parser.add_argument("--json", type=argtypes.output_file, metavar="FILE",
                        help="write the figures as JSON")
    parser.set_defaults(func=_eval)


def _decoder(model: str) -> tuple[Decoder, str]:
    """The decoder MODEL names, and what it is: a model file first, else a decoder name."""
    from decoder.registry import available_decoders, create_decoder, load_decoder
    from skin.errors import ConfigError

    if os.path.exists(model):
        return load_decoder(model), "model file"
    if model in available_decoders():
        return create_decoder(model), "decoder"
    raise ConfigError("MODEL", f"{model!r} is neither a model file nor a decoder name "
                      f"(decoders: {', '.join(available_decoders())})")


def _check_pillars(decoder: Decoder, model: str, dataset: Dataset, data: str) -> None:
    """A model fitted on one mode cannot decode the other: say so in one line."""
    from skin.errors import ConfigError

    have = dataset.resistance_ohm.shape[-1]
    fitted = getattr(decoder, "pillars_", None)
    r0 = getattr(decoder, "r0_ohm", None)
    if fitted is None and r0 is not None:
        fitted = r0.shape[-1]
    if fitted is not None and fitted != have:
        raise ConfigError(data, f"{_MODE_NAMES[have]} resistances ({have} pillar"
                          f"{'s' if have > 1 else ''} per taxel), but {model} was fitted on "
                          f"{_MODE_NAMES[fitted]} input ({fitted} pillar"
                          f"{'s' if fitted > 1 else ''}); evaluate it on a dataset of a "
                          f"{_MODE_NAMES[fitted]} scene")


def _decode(decoder: Decoder, name: str, dataset: Dataset, data: str) -> Decoded:
    from skin.errors import ConfigError, NotFittedError

    try:
        return decoder.decode(dataset.resistance_ohm)
    except NotFittedError as err:
        raise ConfigError("MODEL", f"decoder {name!r} needs training first: `skin train "
                          f"{name} --data TRAIN.npz -o M.msgpack`, then `skin eval "
                          f"M.msgpack {data}`") from err


def _warn_constants(decoder: Decoder, model: str, dataset: Dataset) -> None:
    import logging

    from skin.constants import SensorConstants

    own = getattr(decoder, "constants", None)
    truth = SensorConstants.from_dict(dataset.meta["constants"])
    if isinstance(own, SensorConstants) and own != truth:
        differ = [k for k, v in own.to_dict().items() if truth.to_dict().get(k) != v]
        logging.getLogger(__name__).warning(
            "%s assumes other sensor constants than the dataset's (%s): the error includes "
            "that mismatch", model, ", ".join(differ))


def _eval(args: argparse.Namespace) -> int:
    import numpy as np

    from decoder.metrics import evaluate, rmse_per_axis
    from decoder.reasons import reason_name
    from skin.atomic import atomic_write
    from skin.constants import SensorConstants
    from skin.dataset import read_dataset

    decoder, kind = _decoder(args.model)
    dataset = read_dataset(args.data)
    _check_pillars(decoder, args.model, dataset, args.data)
    _warn_constants(decoder, args.model, dataset)
    decoded = _decode(decoder, args.model, dataset, args.data)
    mode = dataset.meta["mode"]
    constants = SensorConstants.from_dict(dataset.meta["constants"])
    report = evaluate(dataset.force_N, decoded.force_N, decoded.valid, mode=mode,
                      constants=constants)
    axes = rmse_per_axis(dataset.force_N, decoded.force_N, decoded.valid, mode=mode)
    codes, counts = np.unique(decoded.reason, return_counts=True)
    taxels = int(decoded.reason.size)
    invalid = {reason_name(int(c)): int(n) for c, n in zip(codes, counts, strict=True) if c}
    samples, patches = dataset.resistance_ohm.shape[:2]
    record: dict[str, Any] = {
        "model": args.model, "model_kind": kind, "decoder": type(decoder).name,
        "data": args.data, "samples": samples, "patches": patches, "mode": mode,
        "full_scale_N": constants.full_scale_force_N,
        "metrics": {k: _finite(v) for k, v in report.to_dict().items()},
        "rmse_per_axis_N": {k: _finite(v) for k, v in axes.items()},
        "taxels": taxels,
        "covered": {"taxels": report.covered, "share": report.covered_share},
        "invalid": {"taxels": sum(invalid.values()),
                    "share": sum(invalid.values()) / taxels if taxels else 0.0,
                    "by_reason": {name: {"taxels": n, "share": n / taxels}
                                  for name, n in invalid.items()}},
    }
    for line in _lines(record):
        print(line)
    if args.json:
        with atomic_write(args.json) as handle:
            handle.write(json.dumps(record, indent=2, allow_nan=False).encode() + b"\n")
    return NO_RESULT if report.covered == 0 else 0


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _num(value: float | None, fmt: str, unit: str = "") -> str:
    return "n/a" if value is None else f"{value:{fmt}}{unit}"


def _lines(record: dict[str, Any]) -> list[str]:
    m, fs = record["metrics"], record["full_scale_N"]
    compared = "Fz compared" if record["mode"] == "z" else "Fx, Fy, Fz compared"
    invalid, covered = record["invalid"], record["covered"]
    reasons = ", ".join(f"{name} {100 * r['share']:.2f} %" for name, r in
                        invalid["by_reason"].items()) or "none"
    axes = ", ".join(f"F{axis} {_num(v, '.4f', ' N')}"
                     for axis, v in record["rmse_per_axis_N"].items())
    s = "" if record["patches"] == 1 else "es"
    what = (f"{record['model']} ({record['decoder']}) on {record['data']}: "
            f"{record['samples']:,} samples x {record['patches']} patch{s}, "
            f"{_MODE_NAMES[1 if record['mode'] == 'z' else 3]}")
    if not covered["taxels"]:
        return [f"{what}: no result: every taxel masked ({invalid['taxels']:,} of "
                f"{record['taxels']:,}: {reasons}), so no error covers anything"]
    return [
        f"{what} ({compared}); the figures cover {covered['taxels']:,} of "
        f"{record['taxels']:,} taxels ({100 * covered['share']:.2f} %)",
        f"  AveRelErr (Eq. 22)       {_num(m['ave_rel_err_pct'], '.3f', ' %')}",
        f"  floored (|F| >= {0.05 * fs:g} N)  {_num(m['ave_rel_err_floored_pct'], '.3f', ' %')}",
        f"  RMSE                     {_num(m['rmse_N'], '.4f', ' N')} = "
        f"{_num(m['rmse_pct_fs'], '.3f', ' %')} of full scale ({fs:g} N)",
        f"  RMSE per axis            {axes}",
        f"  RMSE edge / centre       {_num(m['rmse_edge_N'], '.4f')} / "
        f"{_num(m['rmse_centre_N'], '.4f', ' N')}",
        f"  max abs error            {_num(m['max_abs_err_N'], '.4f', ' N')}",
        f"  max rel. error, floored  {_num(m['max_rel_err_floored_pct'], '.2f', ' %')}",
        f"  masked taxels            {invalid['taxels']:,} of {record['taxels']:,} "
        f"({100 * invalid['share']:.2f} %): {reasons}",
    ]
