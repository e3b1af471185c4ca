"""A probe pressed at known points on a robot's links: the patches' true taxel forces, and
the truth of each press (its point and force in the link's frame).

A *probe scene* (``examples/robot/probe.toml``) lists presses, each a point on a link's
skin (``link``, ``point_m`` in the link's frame). Every press takes ``period_s``: the probe
(a sphere of ``radius_m``) goes in along the skin's normal over ``ramp_s``, holds at
``depth_m`` (``fz_max_N`` under its centre, on a taxel right below it), and comes out over
``ramp_s``; the presses follow one another and start again after the last. On every patch
of that link the press is the Hertzian sphere of :func:`sim.contact.sphere_fz` at the
point's patch-frame (u, v) (on a curved patch, u is the arc length: the sphere's distance to
a taxel is measured along the skin), so a press near the border of two patches loads both.

Where the patches are (their :class:`skin.placement.PatchPlacement`) comes from the
caller, as the host's config says it: the simulator and the host read one placement.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sim.contact import sphere_fz
from sim.effects.noise import Noise, NoiseParams
from sim.pipeline import Pipeline
from sim.rng import stream
from sim.scene import Scene, scene_from_dict
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.errors import ConfigError
from skin.inputs import fields
from skin.inputs.tomlfile import read_toml
from skin.placement import PatchPlacement

F64 = NDArray[np.float64]
ON_SURFACE_M = 1e-4
"""A press point must lie this close to the skin of a patch of its link."""


@dataclass(frozen=True)
class Press:
    link: str
    point_m: tuple[float, float, float]


@dataclass(frozen=True)
class ProbeScene:
    name: str
    presses: tuple[Press, ...]
    rate_hz: float = 100.0
    period_s: float = 0.6
    ramp_s: float = 0.15
    depth_m: float = 0.003
    radius_m: float = 0.04
    fz_max_N: float = 4.0
    effects: Mapping[str, Any] = field(default_factory=dict)
    source: str = ""

    def scene(self, node_ids: tuple[int, ...], seed: int = 0) -> Scene:
        """The patches with the probe scene's effects, as a :class:`sim.Scene`."""
        return scene_from_dict({
            "scene": {"name": self.name, "mode": "xyz", "rate_hz": self.rate_hz, "seed": seed},
            "patches": [{"node_id": n} for n in node_ids], "effects": dict(self.effects)})


_NUMBERS = {"rate_hz": (1e-3, 1e4), "period_s": (1e-3, 1e4), "ramp_s": (0.0, 1e4),
            "depth_m": (1e-9, 0.1), "radius_m": (1e-6, 1.0), "fz_max_N": (0.0, 1e3)}


def load_probe_scene(path: str | Path) -> ProbeScene:
    """A probe scene file; errors name the file and the dotted field."""
    data = read_toml(path, "scene")
    try:
        return _probe_from_dict(data, str(path))
    except ConfigError as err:
        raise err.in_file(str(path)) from err


def _probe_from_dict(data: Mapping[str, Any], source: str) -> ProbeScene:
    fields.known_keys(data, ("probe", "presses", "effects"), "")
    probe = data.get("probe", {})
    if not isinstance(probe, Mapping):
        raise ConfigError("probe", "must be a table ([probe])")
    fields.known_keys(probe, ("name", *_NUMBERS), "probe")
    values: dict[str, Any] = {}
    for key, value in probe.items():
        if key == "name":
            values[key] = fields.text(value, "probe.name", 256)
        else:
            low, high = _NUMBERS[key]
            values[key] = fields.number(value, f"probe.{key}", high=high, above=low)
    tables = data.get("presses")
    if not isinstance(tables, list) or not tables or not all(isinstance(t, dict)
                                                            for t in tables):
        raise ConfigError("presses", "list the presses as [[presses]] tables")
    presses = []
    for i, table in enumerate(tables):
        where = f"presses[{i}]"
        fields.known_keys(table, ("link", "point_m"), where)
        link = table.get("link")
        if not isinstance(link, str) or not link:
            raise ConfigError(f"{where}.link", f"must name a link, got {fields.shown(link)}")
        point = table.get("point_m")
        if not isinstance(point, list) or len(point) != 3:
            raise ConfigError(f"{where}.point_m", f"must be [x, y, z] in metres, got "
                              f"{fields.shown(point)}")
        x, y, z = (fields.number(v, f"{where}.point_m[{k}]", -1e3, 1e3)
                   for k, v in enumerate(point))
        presses.append(Press(link, (x, y, z)))
    scene = ProbeScene(values.pop("name", Path(source).stem), tuple(presses), **values,
                       effects=dict(data.get("effects", {})), source=source)
    if 2 * scene.ramp_s > scene.period_s:
        raise ConfigError("probe.ramp_s", f"two ramps ({2 * scene.ramp_s:g} s) are longer than "
                          f"period_s ({scene.period_s:g} s)")
    scene.scene((1,))  # the effects checked now, not at the first run
    return scene


@dataclass(frozen=True)
class ProbeRun:
    """``n`` steps of a probe scene on ``patches`` (node-IDs in order)."""

    node_ids: tuple[int, ...]
    force_N: F64  # (n, patches, 9, 3) the true taxel forces, each taxel's own axes
    resistance_ohm: F64  # (n, patches, 9, 3) as read out, through the scene's effects
    press: NDArray[np.intp]  # (n,) the press under way (index into presses)
    depth_m: F64  # (n,) the probe's depth (0: off the skin)
    hold: NDArray[np.bool_]  # (n,) the probe holds its full depth


def check_presses(scene: ProbeScene, placements: Mapping[int, PatchPlacement]) -> None:
    """Every press on a link some patch is on, and on its skin."""
    for i, press in enumerate(scene.presses):
        mine = [p for p in placements.values() if p.link == press.link]
        if not mine:
            raise ConfigError(f"presses[{i}].link", f"no patch on link {press.link!r}",
                              source=scene.source or None)
        heights = [abs(float(p.to_patch(press.point_m)[1])) for p in mine]
        if min(heights) > ON_SURFACE_M:
            raise ConfigError(f"presses[{i}].point_m", f"{min(heights) * 1e3:.2f} mm off the "
                              f"skin of link {press.link!r}", source=scene.source or None)


def run_probe(scene: ProbeScene, placements: Mapping[int, PatchPlacement], steps: int, *,
              seed: int = 0, constants: SensorConstants = DEFAULT_CONSTANTS) -> ProbeRun:
    """The first ``steps`` steps of ``scene`` on the patches ``placements`` places."""
    check_presses(scene, placements)
    nodes = tuple(sorted(placements))
    pitch = constants.taxel_pitch_m
    k = np.arange(steps)
    t = k / scene.rate_hz
    press = (np.floor(t / scene.period_s).astype(np.intp)) % len(scene.presses)
    phase = np.mod(t, scene.period_s)
    ramp = scene.ramp_s
    rise = np.clip(phase / ramp, 0.0, 1.0) if ramp > 0 else np.ones(steps)
    fall = np.clip((scene.period_s - phase) / ramp, 0.0, 1.0) if ramp > 0 else np.ones(steps)
    share = np.minimum(rise, fall)
    depth = scene.depth_m * share
    force = np.zeros((steps, len(nodes), 9, 3))
    for j, press_ in enumerate(scene.presses):
        rows = np.flatnonzero(press == j)
        for i, node in enumerate(nodes):
            placement = placements[node]
            if placement.link != press_.link:
                continue
            uv, _ = placement.to_patch(press_.point_m)
            force[rows, i, :, 2] = sphere_fz(
                np.full(rows.size, uv[0]), np.full(rows.size, uv[1]), depth[rows],
                radius_m=scene.radius_m, depth_max_m=scene.depth_m, fz_max_N=scene.fz_max_N,
                pitch_m=pitch)
    sim_scene = scene.scene(nodes, seed)
    pipeline = Pipeline(sim_scene, constants, seed, len(nodes))
    resistance = pipeline.resistance(force, t)
    noise = sim_scene.effects.get("noise")
    if isinstance(noise, NoiseParams):
        Noise(noise, constants, 3, stream(seed, "noise")).apply(resistance)
    return ProbeRun(nodes, force, resistance, press, depth, share >= 1.0)
