"""``skin bench robot``: contacts on the example robot's links against the probe scene's
truth (``skin.benchmarks.robot``, docs/robot.md)."""

from __future__ import annotations

import argparse
from typing import Any


def run_robot(args: argparse.Namespace) -> dict[str, Any]:
    from skin.benchmarks.robot import run_robot_benchmark
    from skin.commands.bench.report import Stages

    stages = Stages(2)
    try:
        result = run_robot_benchmark(quick=args.quick, decoder=args.decoder or "deconv",
                                     stage=stages)
    finally:
        stages.close()
    print_robot(result)
    return result


def _mm(stats: dict[str, float | None]) -> str:
    return " / ".join("-" if stats[k] is None else f"{stats[k]:.2f}" for k in ("p50", "p95"))


def print_robot(r: dict[str, Any]) -> None:
    force = r["contact_force_err_pct_fs"]
    cross = r["cross_patch_presses"]
    print(f"contacts on the robot ({r['decoder']} decoder, {r['cycles']:,} cycles): "
          f"links {', '.join(r['links'])}")
    print(f"contact point error p50 / p95: {_mm(r['contact_point_err_mm'])} mm held "
          f"({r['held_samples']:,} samples), {_mm(r['contact_point_err_mm_all'])} mm over "
          f"every sample in contact; missed {r['missed_samples']}")
    print(f"net force error p50 / p95 / rms: {_mm(force)} / {force['rms']:.2f} % of "
          f"{r['full_scale_N']:g} N")
    print(f"presses across two patches: {cross['count']}, reported as one contact: "
          f"{cross['merged']}")
