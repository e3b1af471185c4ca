"""Scenes: TOML files of patches, loads and effects, parsed into frozen dataclasses.

The file is read by :func:`skin.inputs.tomlfile.read_toml` (UTF-8, nesting, no NaN or
infinity anywhere); every field is typed and ranged (``RANGES`` of each parameter class).
Unknown keys, kinds and effects are errors that name the file and the dotted field, e.g.
``my.toml: loads[0].kind: unknown load 'foo'; known: ...``.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from sim.effects import EFFECT_PARAMS, EFFECTS
from sim.effects.crosstalk import CrosstalkParams, crosstalk_matrix
from sim.effects.faults import FaultsParams
from sim.loads import LOAD_PARAMS
from sim.params import build, one_of, positive
from skin.errors import ConfigError
from skin.inputs import fields
from skin.inputs.tomlfile import parse_toml, read_toml

MODES = ("z", "xyz")
POSITION_LIMIT_M = 1000.0


@dataclass(frozen=True)
class PatchSpec:
    """One patch: its CANopen node id (1..127) and where it sits on the robot, in metres."""

    node_id: int
    position_m: tuple[float, float] = (0.0, 0.0)


@dataclass(frozen=True)
class LoadSpec:
    kind: str
    patches: tuple[int, ...]  # node ids
    params: Any


@dataclass(frozen=True)
class _Header:
    name: str = ""
    description: str = ""
    mode: str = "z"
    rate_hz: float = 100.0
    seed: int = 0

    RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "rate_hz": (1e-3, 1e4), "seed": (0, 2**63 - 1)}

    def check(self, where: str) -> None:
        if not self.name:
            raise ConfigError(f"{where}.name", "missing or empty")
        one_of(self.mode, MODES, f"{where}.mode", "mode")
        positive(self.rate_hz, f"{where}.rate_hz")
        if self.seed < 0:
            raise ConfigError(f"{where}.seed", f"must be >= 0, got {self.seed}")


@dataclass(frozen=True)
class Scene:
    name: str
    mode: str
    rate_hz: float
    seed: int
    patches: tuple[PatchSpec, ...]
    description: str = ""
    loads: tuple[LoadSpec, ...] = ()
    effects: Mapping[str, Any] = field(default_factory=dict)
    source: str = field(default="", compare=False)
    """The file the scene was read from, for messages ("" when built in code)."""

    @property
    def pillars(self) -> int:
        return 1 if self.mode == "z" else 3

    @property
    def node_ids(self) -> tuple[int, ...]:
        return tuple(p.node_id for p in self.patches)

    def crosstalk_matrix(self) -> NDArray[np.float64]:
        """(9, 9) M with F_eff = M @ F per component; identity without elastic_crosstalk."""
        p = self.effects.get("elastic_crosstalk")
        if not isinstance(p, CrosstalkParams):
            return np.eye(9)
        return crosstalk_matrix(p.coupling, p.diagonal_coupling)

    def listed_effects(self) -> list[str]:
        """The listed effects, in pipeline order."""
        return [name for name in EFFECTS if name in self.effects]

    def to_dict(self) -> dict[str, Any]:
        """JSON-able, with every default filled in; scene_from_dict(to_dict()) == self."""
        return {
            "scene": {"name": self.name, "description": self.description, "mode": self.mode,
                      "rate_hz": self.rate_hz, "seed": self.seed},
            "patches": [{"node_id": p.node_id, "position_m": list(p.position_m)}
                        for p in self.patches],
            "loads": [{"kind": ld.kind, "patches": list(ld.patches),
                       **dataclasses.asdict(ld.params)} for ld in self.loads],
            "effects": {name: dataclasses.asdict(self.effects[name])
                        for name in self.listed_effects()},
        }


def _table_list(data: Mapping[str, Any], key: str) -> list[dict[str, Any]]:
    items = data.get(key, [])
    if not isinstance(items, list) or not all(isinstance(t, dict) for t in items):
        raise ConfigError(key, f"must be an array of tables ([[{key}]])")
    return items


def _patch(table: dict[str, Any], where: str) -> PatchSpec:
    fields.known_keys(table, ("node_id", "position_m"), where)
    node = fields.node_id(table.get("node_id"), f"{where}.node_id")
    pos = table.get("position_m", [0.0, 0.0])
    if not (isinstance(pos, list) and len(pos) == 2):
        raise ConfigError(f"{where}.position_m", f"must be [x, y] in metres, got "
                          f"{fields.shown(pos)}")
    x, y = (fields.number(v, f"{where}.position_m[{k}]", -POSITION_LIMIT_M, POSITION_LIMIT_M)
            for k, v in enumerate(pos))
    return PatchSpec(node, (x, y))


def _load(table: dict[str, Any], where: str, nodes: tuple[int, ...]) -> LoadSpec:
    rest = dict(table)
    kind = rest.pop("kind", None)
    if not isinstance(kind, str):
        raise ConfigError(f"{where}.kind", f"missing; known: {', '.join(LOAD_PARAMS)}")
    one_of(kind, tuple(LOAD_PARAMS), f"{where}.kind", "load")
    patches = rest.pop("patches", list(nodes))
    if not isinstance(patches, list) or not patches:
        raise ConfigError(f"{where}.patches", "must be a non-empty list of node ids")
    for i, node in enumerate(patches):
        fields.node_id(node, f"{where}.patches[{i}]")
        if node not in nodes:
            raise ConfigError(f"{where}.patches[{i}]", f"no patch with node_id {node!r}")
    if len(set(patches)) != len(patches):
        raise ConfigError(f"{where}.patches", "lists a node id twice")
    return LoadSpec(kind, tuple(patches), build(LOAD_PARAMS[kind], rest, where))


def _effects(table: Any, mode: str, nodes: tuple[int, ...]) -> dict[str, Any]:
    if not isinstance(table, dict):
        raise ConfigError("effects", "must be a table of [effects.<name>] tables")
    effects: dict[str, Any] = {}
    for name, params in table.items():
        where = f"effects.{name}"
        one_of(name, EFFECTS, where, "effect")
        if not isinstance(params, dict):
            raise ConfigError(where, "must be a table ([effects.<name>])")
        cls = EFFECT_PARAMS[name]
        effects[name] = (cls.from_table(params, where) if hasattr(cls, "from_table")
                         else build(cls, params, where))
    faults = effects.get("faults")
    if isinstance(faults, FaultsParams):
        for i, spec in enumerate(faults.pillars):
            where = f"effects.faults.pillars[{i}]"
            if spec.node_id not in nodes:
                raise ConfigError(f"{where}.node_id", f"no patch with node_id {spec.node_id}")
            if mode == "z" and spec.pillar != "z":
                raise ConfigError(
                    f"{where}.pillar", f"pillar {spec.pillar!r} is not read in mode 'z'"
                )
    return effects


def scene_from_dict(data: Mapping[str, Any]) -> Scene:
    """Validate a parsed TOML document (or Scene.to_dict()) into a Scene."""
    if not isinstance(data, Mapping):
        raise ConfigError("scene file", f"must be a table, got {fields.shown(data)}")
    fields.known_keys(data, ("scene", "patches", "loads", "effects"), "")
    header_table = data.get("scene")
    if not isinstance(header_table, dict):
        raise ConfigError("scene", "missing [scene] table")
    header = build(_Header, header_table, "scene")
    fields.text(header.name, "scene.name", 256)
    patches = tuple(_patch(t, f"patches[{i}]") for i, t in enumerate(_table_list(data, "patches")))
    if not patches:
        raise ConfigError("patches", "a scene needs at least one [[patches]]")
    nodes = tuple(p.node_id for p in patches)
    if len(set(nodes)) != len(nodes):
        raise ConfigError("patches", "two patches share a node_id")
    loads = tuple(_load(t, f"loads[{i}]", nodes) for i, t in enumerate(_table_list(data, "loads")))
    effects = _effects(data.get("effects", {}), header.mode, nodes)
    return Scene(header.name, header.mode, header.rate_hz, header.seed, patches,
                 header.description, loads, effects)


def shipped_scenes() -> list[str]:
    """Names of the scenes shipped in the package."""
    folder = importlib.resources.files("sim.scenes")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def load_scene(name_or_path: str | os.PathLike[str]) -> Scene:
    """A shipped scene by name ("paper", "indenter", ...) or a scene file by path."""
    text = str(name_or_path)
    if isinstance(name_or_path, os.PathLike) or text.endswith(".toml") or os.sep in text:
        path = Path(name_or_path)
        if not path.is_file():
            raise ConfigError("scene", f"no scene file {text!r}")
        source, data = str(path), read_toml(path, "scene")
    else:
        shipped = importlib.resources.files("sim.scenes") / f"{text}.toml"
        if not shipped.is_file():
            known = ", ".join(shipped_scenes())
            raise ConfigError("scene", f"unknown scene {text!r}; shipped: {known}; or a .toml path")
        source = f"scene {text!r}"
        data = parse_toml(shipped.read_bytes(), source, "scene")
    try:
        return replace(scene_from_dict(data), source=source)
    except ConfigError as err:
        raise err.in_file(source) from err


def on_patches(scene: Scene, patches: int, spacing_m: float = 0.05) -> Scene:
    """``scene``'s loads and effects on ``patches`` patches at node-IDs 1..N, on a square
    grid ``spacing_m`` apart, every load on every patch (faults kept on the patches that
    remain): how one scene stands for a skin of any size."""
    fields.integer(patches, "patches", 1, len(fields.NODE_IDS))  # each its own node-ID
    if patches == len(scene.patches) and scene.node_ids == tuple(range(1, patches + 1)):
        return scene
    data = scene.to_dict()
    side = math.ceil(math.sqrt(patches))
    data["patches"] = [{"node_id": k + 1, "position_m": [spacing_m * (k % side),
                                                         spacing_m * (k // side)]}
                       for k in range(patches)]
    for load in data["loads"]:
        load["patches"] = list(range(1, patches + 1))
    faults = data["effects"].get("faults")
    if faults is not None:
        faults["pillars"] = [p for p in faults["pillars"] if p["node_id"] <= patches]
    return replace(scene_from_dict(data), source=scene.source)
