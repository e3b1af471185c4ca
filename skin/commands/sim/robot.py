"""``skin sim run PROBE.toml --robot HOST.toml``: the probe scene's presses on the patches
a host config places on the robot's links (``sim.probe``, docs/robot.md)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from canbus.device.source import ArraySource
    from sim import Scene


def probe_source(args: argparse.Namespace) -> tuple[Scene, ArraySource]:
    """The scene of the placed patches and its source: one loop of the presses computed
    at once (the scene's effects, noise included), replayed for as long as the run lasts."""
    from canbus.device.source import ArraySource
    from canbus.master.hostconfig import load_host_config
    from sim.probe import load_probe_scene, run_probe
    from skin.errors import ConfigError

    if args.patches is not None:
        raise ConfigError("--patches", "the robot's host config says which patches there are")
    if args.truth:
        raise ConfigError("--truth", "not with --robot: the probe's truth is skin bench robot's")
    config = load_host_config(args.robot)
    placements = {p.node_id: p.placement for p in config.patches if p.placement is not None}
    if not placements:
        raise ConfigError("--robot", f"{args.robot}: no patch is placed on a link")
    probe = load_probe_scene(args.scene)
    seed = 0 if args.seed is None else args.seed
    steps = max(1, round(len(probe.presses) * probe.period_s * probe.rate_hz))
    run = run_probe(probe, placements, steps, seed=seed)
    return probe.scene(run.node_ids, seed), ArraySource(run.resistance_ohm, run.node_ids)
