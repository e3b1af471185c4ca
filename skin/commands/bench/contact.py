"""``skin bench contact``: the contact summary against the simulator's truth on ``indenter``,
``slide``, ``grasp`` and ``stick-slip``, and its cost in the data plane
(``skin.benchmarks.contact``)."""

from __future__ import annotations

import argparse
from typing import Any

from skin.commands.common import argtypes


def run_contact(args: argparse.Namespace) -> dict[str, Any]:
    from skin.benchmarks.contact import SCENES, run_contact_benchmark
    from skin.commands.bench.report import Stages
    from skin.contact import ContactParams
    from skin.errors import ConfigError

    scenes = args.scene or list(SCENES)
    for name in scenes:
        if name not in SCENES:
            raise ConfigError("--scene", f"one of {', '.join(SCENES)}, got {name!r}")
    try:
        params = ContactParams() if args.taxel_contact_N is None else ContactParams(
            taxel_contact_N=args.taxel_contact_N)
    except ConfigError as err:
        raise ConfigError("--taxel-contact-N", err.problem) from err
    stages = Stages(len(scenes) + 1)
    try:
        return run_contact_benchmark(quick=args.quick, decoder=args.decoder or "deconv",
                                     params=params, scenes=scenes, stage=stages)
    finally:
        stages.close()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``skin bench``'s options that only ``contact`` reads."""
    parser.add_argument("--decoder", metavar="NAME",
                        help="contact: the decoder whose forces are summarised (default "
                             "deconv, trained on another run of each scene)")
    parser.add_argument("--scene", action="append", metavar="NAME",
                        help="contact: only this scene (repeatable; default all four)")
    parser.add_argument("--taxel-contact-N", metavar="N",
                        type=argtypes.number("threshold", low=0.0, high=100.0, unit="N"),
                        help="contact: the taxel contact threshold (default 0.12)")


def _number(value: float | None, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


def print_contact(result: dict[str, Any]) -> None:
    from skin.commands.common.tables import show

    rows = []
    for name, s in result["scenes"].items():
        delay = s["slip_delay_cycles"]
        oracle = s["oracle"]
        rows.append([
            name, f"{s['cop_samples']:,}", _number(s["cop_err_mm"]["p50"], ".3f"),
            _number(s["cop_err_mm"]["p95"], ".3f"),
            _number(s["cop_err_mm_from_1N"]["p95"], ".3f"),
            _number(oracle["cop_err_mm"]["p95"], ".3f"),
            _number(s["net_fz_err_pct_fs"], ".2f"),
            _number(s["net_fz_err_pct_fs_stats"]["p95"], ".2f"),
            _number(oracle["net_fz_err_pct_fs"], ".2f"),
            f"{s['slip_onsets']}", _number(delay["p50"], "g"),
            f"{_number(delay['min'], 'd')}..{_number(delay['max'], 'd')}",
            f"{s['slip_missed']}", f"{s['slip_false_alarms']}",
            f"{100 * s['contact_agreement']:.1f} %"])
    show(f"contact summary against the truth ({result['decoder']} decoder; oracle: knows the "
         "true crosstalk)",
         ["scene", "CoP samples", "CoP p50 mm", "CoP p95 mm", "p95 from 1 N", "oracle p95",
          "Fz rms % FS",
          "Fz p95 % FS", "oracle rms", "slip onsets", "delay p50", "delay range", "missed",
          "false alarms", "contact agrees"], rows,
         caption=f"full scale {result['full_scale_N']:g} N; delays in SYNC cycles, "
                 f"±{result['tolerance_cycles']} tolerated")
    c = result["cost"]
    print(f"cost: {c['with_us_per_sample']:.2f} µs of CPU per patch-sample with the summary, "
          f"{c['without_us_per_sample']:.2f} without (data plane, {c['patches']} patches a "
          f"cycle, {c['repeats']} runs interleaved): cost_ratio {result['cost_ratio']:.3f}; "
          f"force frames out {c['frames_out_with']:,} against {c['frames_out_without']:,}; "
          f"the eighth frame alone {c['frame_ratio']:.3f}")
