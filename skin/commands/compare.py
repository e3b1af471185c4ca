"""``skin compare FORCES --reference REF``: decoded forces against reference forces.

FORCES is what ``skin decode`` wrote (.csv or .npz: one sample per patch per SYNC, with its
SYNC counter and time); REF a reference file (``skin.reference``: what a load cell measured,
or ``skin sim run --truth``). Each patch's samples are joined to its reference samples as
``skin dataset from-recording`` joins them (``canbus.tools.join``: by SYNC counter, or by
time with a given or estimated clock offset), and compared with ``decoder.metrics``: the
floored AveRelErr (|F| >= 5 % of full scale), the plain one, RMSE in N and per axis, over
the taxels the decoder did not mask, with the share of the joined taxels they cover. The
last step of the calibration recipe (docs/calibrate.md): the forces the host publishes
with a patch's own model, against what the patch really felt.

Exit status: 0; 3 when no joined taxel was decoded (no result); 1 for bad input.
"""

from __future__ import annotations

import argparse
import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from skin.commands.common import argtypes

NO_RESULT = 3
_CSV_COLUMNS = ("cycle", "sync_counter", "time_s", "patch", "force_node", "taxel", "fx_N",
                "fy_N", "fz_N", "valid", "reason", "complete")


@dataclass
class Decoded:
    """``skin decode``'s samples: (n,) time, counter, patch; (n, 9, 3) forces; (n, 9) valid."""

    time_s: Any
    sync: Any
    patch: Any
    force_N: Any
    valid: Any


def add_subparser(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "compare", help="decoded forces (skin decode) against reference forces",
        description="Join each patch's decoded samples (skin decode's .csv or .npz) to its "
                    "reference samples by SYNC counter or by time, and report the floored "
                    "AveRelErr, AveRelErr, RMSE per axis and the share of the taxels they "
                    "cover.")
    parser.add_argument("forces", metavar="FORCES", help="skin decode's output (.csv, .npz)")
    parser.add_argument("--reference", required=True, metavar="REF",
                        help="reference forces (.csv or .npz, docs/calibrate.md)")
    parser.add_argument("--node", type=argtypes.node_id, action="append", metavar="N",
                        help="compare only patch N (repeatable; default: every patch in both)")
    parser.add_argument("--join", choices=("sync", "time"), default=None,
                        help="by SYNC counter (default when both have one) or by time")
    parser.add_argument("--clock-offset-ms", default=None, metavar="MS",
                        type=argtypes.number("milliseconds", low=-10**13, high=10**13, unit="ms"),
                        help="reference time + offset = the decode's time (default: estimated)")
    parser.add_argument("--mode", choices=("auto", "z", "xyz"), default="auto",
                        help="compare Fz only (z) or all three (xyz); auto: z for a patch "
                             "decoded without shear, else xyz")
    parser.add_argument("--json", type=argtypes.output_file, metavar="FILE",
                        help="write the figures as JSON")
    parser.set_defaults(func=_compare)


def read_decoded(path: str) -> Decoded:
    """``skin decode``'s output; one line naming the file and row for anything else."""
    import numpy as np

    from skin.errors import ConfigError

    suffix = Path(path).suffix.lower()
    if suffix == ".npz":
        try:
            with np.load(path) as z:
                return Decoded(z["time_s"].astype(np.float64), z["sync_counter"].astype(np.int64),
                               z["patch"].astype(np.int64), z["force_N"].astype(np.float64),
                               z["valid"].astype(bool))
        except KeyError as err:
            raise ConfigError(path, f"not skin decode's output: no array {err}") from err
        except (OSError, ValueError) as err:
            raise ConfigError(path, f"cannot read it: {err}") from err
    if suffix != ".csv":
        raise ConfigError(path, f"unknown format {suffix or '(no suffix)'!r}: give skin "
                                "decode's .csv or .npz")
    return _read_csv(path)


def _read_csv(path: str) -> Decoded:
    import numpy as np

    from skin.errors import ConfigError

    rows: list[list[str]] = []
    with open(path, newline="", encoding="utf-8") as handle:
        reader = csv.reader(handle)
        header = next(reader, None)
        if header != list(_CSV_COLUMNS):
            raise ConfigError(path, "row 1: not skin decode's header "
                                    f"({','.join(_CSV_COLUMNS)})")
        rows = list(reader)
    if len(rows) % 9:
        raise ConfigError(path, f"row {len(rows) + 1}: {len(rows)} taxel rows, not 9 per sample "
                                "(a cut file?)")
    try:
        table = np.array(rows, dtype=object).reshape(-1, 9, len(_CSV_COLUMNS))
        time_s = table[:, 0, 2].astype(np.float64)
        sync = table[:, 0, 1].astype(np.int64)
        patch = table[:, 0, 3].astype(np.int64)
        force = table[:, :, 6:9].astype(np.float64)
        valid = table[:, :, 9].astype(np.int64).astype(bool)
    except ValueError as err:
        raise ConfigError(path, f"a value is not a number: {err}") from err
    taxels = table[:, :, 5].astype(np.int64)
    bad = np.flatnonzero((taxels != np.arange(9)).any(axis=1))
    if bad.size:
        raise ConfigError(path, f"row {9 * int(bad[0]) + 2}: a sample's taxels are not 0..8 "
                                "in order")
    return Decoded(time_s, sync, patch, force, valid)


def _compare(args: argparse.Namespace) -> int:
    import numpy as np

    from skin.commands.calibrate.output import write_json
    from skin.errors import ConfigError
    from skin.reference import read_reference

    decoded = read_decoded(args.forces)
    ref = read_reference(args.reference)
    both = sorted(set(np.unique(decoded.patch).tolist()) & set(ref.nodes))
    nodes = args.node or both
    missing = [n for n in nodes if n not in both]
    if missing or not nodes:
        raise ConfigError("--node" if args.node else args.reference,
                          f"no patch is in both {args.forces} and {args.reference}" if not nodes
                          else f"patch {missing[0]} is not in both files")
    results = {n: _patch(decoded, ref, n, args) for n in nodes}
    covered = sum(r["covered"] for r in results.values())
    taxels = sum(r["taxels"] for r in results.values())
    head = f"{args.forces} against {args.reference}"
    if not covered:
        print(f"{head}: no result: every joined taxel was masked (or none joined), so no "
              "error covers anything")
    else:
        print(f"{head}: {sum(r['joined'] for r in results.values()):,} samples joined; the "
              f"figures cover {covered:,} of {taxels:,} taxels ({100 * covered / taxels:.2f} %)")
    for n, r in results.items():
        print(_line(n, r))
    if args.json:
        write_json(args.json, {"forces": args.forces, "reference": args.reference,
                               "covered": covered, "taxels": taxels,
                               "patches": {str(n): r for n, r in results.items()}})
    return 0 if covered else NO_RESULT


def _patch(decoded: Decoded, ref: Any, node: int, args: argparse.Namespace) -> dict[str, Any]:
    import numpy as np

    from canbus.tools.join import Series, join
    from decoder.metrics import evaluate, rmse_per_axis

    mine = np.flatnonzero(decoded.patch == node)
    theirs = ref.of_node(node)
    times = decoded.time_s[mine]
    period = float(np.median(np.diff(times))) if times.size > 1 else 0.01
    by = args.join or ("sync" if ref.has_sync and bool(np.any(decoded.sync[mine])) else "time")
    force, valid = decoded.force_N[mine], decoded.valid[mine]
    load = np.where(valid, force[..., 2], 0.0).sum(axis=1)
    pairs = join(Series(times, decoded.sync[mine], load),
                 Series(ref.time_s[theirs], ref.sync[theirs], ref.force_N[theirs][..., 2]
                        .sum(axis=1)),
                 by=by, period_s=period,
                 clock_offset_s=None if args.clock_offset_ms is None
                 else args.clock_offset_ms / 1000.0)
    mode = args.mode
    if mode == "auto":
        shear = force[..., :2][valid]
        mode = "z" if not np.any(shear) else "xyz"
    e = evaluate(ref.force_N[theirs][pairs.reference], force[pairs.recorded],
                 valid[pairs.recorded], mode=mode)
    axes = rmse_per_axis(ref.force_N[theirs][pairs.reference], force[pairs.recorded],
                         valid[pairs.recorded], mode=mode)
    return {"joined": int(pairs.recorded.size), "reference_samples": int(theirs.size),
            "decoded_samples": int(mine.size), "by": by,
            "clock_offset_s": pairs.clock_offset_s, "mode": mode,
            "taxels": e.taxels, "covered": e.covered, "covered_share": e.covered_share,
            "ave_rel_err_floored_pct": _num(e.ave_rel_err_floored_pct),
            "ave_rel_err_pct": _num(e.ave_rel_err_pct), "rmse_N": _num(e.rmse_N),
            "rmse_per_axis_N": {k: _num(v) for k, v in axes.items()},
            "max_abs_err_N": _num(e.max_abs_err_N)}


def _num(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _fmt(value: float | None, unit: str, digits: int = 3) -> str:
    return "-" if value is None else f"{value:.{digits}f}{unit}"


def _line(node: int, r: dict[str, Any]) -> str:
    how = "by SYNC counter" if r["by"] == "sync" else \
        f"by time, clock offset {1000 * r['clock_offset_s']:.1f} ms"
    what = "Fz" if r["mode"] == "z" else "Fx, Fy, Fz"
    axes = ", ".join(f"F{a} {_fmt(v, ' N', 4)}" for a, v in r["rmse_per_axis_N"].items())
    return (f"patch {node}: {r['joined']:,} of {r['reference_samples']:,} reference samples "
            f"joined ({how}); {what} over {r['covered']:,} of {r['taxels']:,} taxels "
            f"({100 * r['covered_share']:.2f} %): floored AveRelErr "
            f"{_fmt(r['ave_rel_err_floored_pct'], ' %')}, AveRelErr "
            f"{_fmt(r['ave_rel_err_pct'], ' %')}, RMSE {_fmt(r['rmse_N'], ' N', 4)} ({axes}), "
            f"max {_fmt(r['max_abs_err_N'], ' N', 4)}")
