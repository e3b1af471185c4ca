"""The host config's robot keys: ``[robot]`` (the robot's URDF) and each patch's place on a
link (``patches[].link``, ``pose``, ``frame``, ``radius_m``), checked into
:class:`skin.placement.PatchPlacement`.

```toml
[robot]
urdf = "arm.urdf"           # relative to the config file; read with yourdfpy ([robot] extra)

[[patches]]
node_id = 1
link = "forearm"
frame = "forearm_skin_1"    # the pose of this URDF frame on the link (fixed joints only) ...
radius_m = 0.05             # ... bent round a cylinder of this radius (absent: flat)

[[patches]]
node_id = 3
link = "palm"
pose = { xyz_m = [0.0, 0.0, 0.01], rpy_deg = [0.0, 0.0, 90.0] }   # ... or given here
```

Every error names the dotted field: ``patches[0].link: no link 'forarm' in arm.urdf``,
``patches[1].frame: no frame 'skin_9' in arm.urdf``, ``patches[2].pose.xyz_m[1]: must be a
number ...``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from skin.errors import ConfigError
from skin.inputs import fields
from skin.placement import PatchPlacement, Pose

PLACEMENT_KEYS = ("link", "pose", "frame", "radius_m")
LIMIT_M = 1000.0
LIMIT_DEG = 3600.0


class Robot:
    """The links and frames of a URDF: each frame's parent link, and the fixed joints."""

    def __init__(self, source: str, parents: Mapping[str, tuple[str, str, str, Pose]],
                 links: set[str]) -> None:
        self.source = source
        self.links = links
        self.parents = parents  # child link -> (joint, joint type, parent link, origin)

    def pose_of(self, frame: str, link: str, where: str) -> Pose:
        """The pose of ``frame`` in ``link``'s frame, through fixed joints only."""
        if frame not in self.links:
            raise ConfigError(f"{where}.frame", f"no frame {frame!r} in {self.source}")
        chain: list[tuple[str, str, str, Pose]] = []
        at = frame
        while at != link:  # up the tree from the frame to the link
            if at not in self.parents or len(chain) > len(self.parents):
                raise ConfigError(f"{where}.frame", f"{frame!r} is not on link {link!r} in "
                                  f"{self.source}")
            chain.append(self.parents[at])
            at = chain[-1][2]
        pose = Pose()
        for joint, kind, _, origin in chain:
            if kind != "fixed":
                raise ConfigError(f"{where}.frame", f"{frame!r} moves on link {link!r}: "
                                  f"joint {joint!r} between them is {kind}")
            pose = pose.then(origin)
        return pose


def read_urdf(value: Any, base: Path) -> Robot:
    """``[robot] urdf``: the file, read with yourdfpy (meshes not loaded)."""
    path = Path(fields.path(value, "robot.urdf"))
    path = path if path.is_absolute() else base / path
    if not path.is_file():
        raise ConfigError("robot.urdf", f"no such file {os.fspath(path)!r}")
    try:
        import yourdfpy
    except ImportError as err:
        raise ConfigError("robot.urdf", "reading a URDF needs yourdfpy: pip install "
                          "'canskin[robot]'") from err
    try:
        urdf = yourdfpy.URDF.load(os.fspath(path), load_meshes=False,
                                  build_scene_graph=False, build_collision_scene_graph=False)
    except Exception as err:  # yourdfpy raises what lxml and its parser raise
        raise ConfigError("robot.urdf", f"{path.name}: not a URDF: "
                          f"{str(err).splitlines()[0] if str(err) else type(err).__name__}"
                          ) from err
    parents = {}
    for name, joint in urdf.joint_map.items():
        origin = np.eye(4) if joint.origin is None else np.asarray(joint.origin, dtype=float)
        try:
            pose = Pose.from_matrix(origin[:3, :3], origin[:3, 3])
        except ConfigError as err:
            raise ConfigError("robot.urdf", f"joint {name!r}: origin {err.problem}") from err
        parents[joint.child] = (name, joint.type, joint.parent, pose)
    return Robot(path.name, parents, set(urdf.link_map))


def robot_from_table(table: Any, base: Path) -> Robot | None:
    if table is None:
        return None
    if not isinstance(table, Mapping):
        raise ConfigError("robot", "must be a table ([robot])")
    fields.known_keys(table, ("urdf",), "robot")
    return read_urdf(table["urdf"], base) if "urdf" in table else None


def _vector(value: Any, where: str, limit: float) -> tuple[float, float, float]:
    if not isinstance(value, list) or len(value) != 3:
        raise ConfigError(where, f"must be [x, y, z], got {fields.shown(value)}")
    x, y, z = (fields.number(v, f"{where}[{k}]", -limit, limit) for k, v in enumerate(value))
    return x, y, z


def _pose(value: Any, where: str) -> Pose:
    if not isinstance(value, Mapping):
        raise ConfigError(where, f"must be a table {{ xyz_m = [x, y, z], rpy_deg = [roll, "
                          f"pitch, yaw] }}, got {fields.shown(value)}")
    fields.known_keys(value, ("xyz_m", "rpy_deg"), where)
    xyz = _vector(value.get("xyz_m", [0.0, 0.0, 0.0]), f"{where}.xyz_m", LIMIT_M)
    rpy = _vector(value.get("rpy_deg", [0.0, 0.0, 0.0]), f"{where}.rpy_deg", LIMIT_DEG)
    return Pose.from_xyz_rpy(xyz, rpy)


def placement_from_table(table: Mapping[str, Any], where: str, robot: Robot | None
                         ) -> PatchPlacement | None:
    """A patch's place on a link, or None when it names no link (a flat skin)."""
    if not any(key in table for key in PLACEMENT_KEYS):
        return None
    if "link" not in table:
        raise ConfigError(f"{where}.link", "missing: pose, frame and radius_m place the patch "
                          "on a link")
    link = table["link"]
    if not isinstance(link, str) or not link:
        raise ConfigError(f"{where}.link", f"must name a link, got {fields.shown(link)}")
    if robot is not None and link not in robot.links:
        raise ConfigError(f"{where}.link", f"no link {link!r} in {robot.source}")
    if "pose" in table and "frame" in table:
        raise ConfigError(f"{where}.frame", "give pose or frame, not both")
    frame = ""
    if "frame" in table:
        frame = table["frame"]
        if not isinstance(frame, str) or not frame:
            raise ConfigError(f"{where}.frame", f"must name a URDF frame, got "
                              f"{fields.shown(frame)}")
        if robot is None:
            raise ConfigError(f"{where}.frame", "needs the robot's URDF: [robot] urdf = ...")
        pose = robot.pose_of(frame, link, where)
    else:
        pose = _pose(table.get("pose", {}), f"{where}.pose")
    radius = None
    if "radius_m" in table:
        radius = fields.number(table["radius_m"], f"{where}.radius_m", high=LIMIT_M, above=0.0)
    return PatchPlacement(link, pose, radius, frame)
