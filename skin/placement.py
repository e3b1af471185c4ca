"""Patches on a robot's links: where each taxel sits, and contacts in the link's frame.

Frames (docs/robot.md):

- the *patch frame* (:mod:`skin.contact`): x right, y up seen from above, z out of the
  skin; taxel k at ((k % 3 - 1)·pitch, (k // 3 - 1)·pitch). A flat patch lies in its
  z = 0 plane. A *curved* patch (``radius_m``) is bent about its y axis round a cylinder of
  that radius whose axis runs through (0, 0, -radius): patch-frame x is then the arc
  length along the surface, so a point (u, v) of the patch is
  (R·sin(u/R), v, R·(cos(u/R) - 1)) with the outward normal (sin(u/R), 0, cos(u/R));
- the *link frame*: the frame of the robot's link the patch is fixed to (URDF's), in
  metres; the patch frame is placed in it by ``pose`` (a rotation, then a translation:
  p_link = R·p_patch + t).

A taxel's force (Fx, Fy, Fz) is in its own local axes (the surface's tangent along u,
along v, and its outward normal n), with canskin's patch-frame signs: Fx, Fy the shear the
object puts on the skin, Fz > 0 pressing in. In the link frame the force is the physical
vector the object puts on the link, R·(Fx·e_u + Fy·e_v − Fz·n): a press points into the
skin, against the normal.
Pure numpy, float64; SI units.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skin.contact import taxel_xy
from skin.errors import ConfigError

F64 = NDArray[np.float64]
ADJOIN_PITCHES = 1.5
"""Two patches' contact regions adjoin when a contact taxel of one lies within this many
pitches of a contact taxel of the other (a direct or diagonal neighbour across the
border of two patches laid edge to edge)."""


def rpy_matrix(rpy_rad: ArrayLike) -> F64:
    """URDF's roll, pitch, yaw (fixed axes x, y, z): R = Rz(yaw)·Ry(pitch)·Rx(roll)."""
    r, p, y = np.asarray(rpy_rad, dtype=np.float64)
    cr, sr, cp, sp, cy, sy = (math.cos(r), math.sin(r), math.cos(p), math.sin(p),
                              math.cos(y), math.sin(y))
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


@dataclass(frozen=True)
class Pose:
    """A rigid transform: p_parent = rotation·p + translation_m."""

    translation_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0),
                                                        (0.0, 0.0, 1.0))

    def __post_init__(self) -> None:
        values = [*self.translation_m, *(v for row in self.rotation for v in row)]
        if len(self.translation_m) != 3 or len(values) != 12:
            raise ConfigError("pose", "must be a 3-vector and a 3x3 rotation")
        if not all(math.isfinite(v) for v in values):
            raise ConfigError("pose", f"must be finite, got {values!r}")

    @classmethod
    def from_xyz_rpy(cls, xyz_m: Sequence[float], rpy_deg: Sequence[float]) -> Pose:
        rotation = rpy_matrix(np.radians(np.asarray(rpy_deg, dtype=np.float64)))
        return cls.from_matrix(rotation, xyz_m)

    @classmethod
    def from_matrix(cls, rotation: ArrayLike, translation_m: ArrayLike) -> Pose:
        r = np.asarray(rotation, dtype=np.float64)
        t = np.asarray(translation_m, dtype=np.float64)
        rows = tuple((float(a), float(b), float(c)) for a, b, c in r.tolist())
        x, y, z = t.tolist()
        return cls((float(x), float(y), float(z)), rows)

    @property
    def matrix(self) -> F64:
        """(3, 3) the rotation."""
        return np.array(self.rotation, dtype=np.float64)

    @property
    def vector(self) -> F64:
        """(3,) the translation."""
        return np.array(self.translation_m, dtype=np.float64)

    def then(self, outer: Pose) -> Pose:
        """This pose seen from ``outer``'s parent: outer ∘ self."""
        return Pose.from_matrix(outer.matrix @ self.matrix,
                                outer.matrix @ self.vector + outer.vector)


@dataclass(frozen=True)
class PatchPlacement:
    """Where a patch sits on the robot: its link, its pose there, and its curvature."""

    link: str
    pose: Pose = field(default_factory=Pose)
    radius_m: float | None = None  # bent round a cylinder of this radius; None: flat
    frame: str = ""  # the URDF frame the pose was taken from ("": given in the config)

    def __post_init__(self) -> None:
        if not self.link:
            raise ConfigError("link", "must name a link")
        if self.radius_m is not None and not (math.isfinite(self.radius_m)
                                              and self.radius_m > 0):
            raise ConfigError("radius_m", f"must be a positive finite length, got "
                              f"{self.radius_m!r}")

    def surface(self, uv_m: ArrayLike) -> tuple[F64, F64, F64]:
        """``(..., 2)`` patch-frame points (u, v) -> their points, outward normals and
        u-tangents in the link frame, each ``(..., 3)``."""
        uv = np.asarray(uv_m, dtype=np.float64)
        u, v = uv[..., 0], uv[..., 1]
        zero, one = np.zeros_like(u), np.ones_like(u)
        if self.radius_m is None:
            point = np.stack([u, v, zero], axis=-1)
            normal = np.stack([zero, zero, one], axis=-1)
            tangent = np.stack([one, zero, zero], axis=-1)
        else:
            r = self.radius_m
            s, c = np.sin(u / r), np.cos(u / r)
            point = np.stack([r * s, v, r * (c - 1.0)], axis=-1)
            normal = np.stack([s, zero, c], axis=-1)
            tangent = np.stack([c, zero, -s], axis=-1)
        rot, t = self.pose.matrix, self.pose.vector
        out: tuple[F64, F64, F64] = (point @ rot.T + t, normal @ rot.T, tangent @ rot.T)
        return out

    def to_patch(self, point_m: ArrayLike) -> tuple[F64, F64]:
        """``(..., 3)`` link-frame points -> their patch-frame (u, v) ``(..., 2)`` on the
        surface (the nearest point of a flat patch's plane; of a curved patch, along the
        cylinder's radius) and their height over it ``(...,)``."""
        p = (np.asarray(point_m, dtype=np.float64) - self.pose.vector) @ self.pose.matrix
        if self.radius_m is None:
            return p[..., :2], p[..., 2]
        r = self.radius_m
        angle = np.arctan2(p[..., 0], p[..., 2] + r)
        height = np.hypot(p[..., 0], p[..., 2] + r) - r
        return np.stack([r * angle, p[..., 1]], axis=-1), height

    def taxel_frames(self, pitch_m: float) -> tuple[F64, F64]:
        """Each taxel's centre ``(9, 3)`` and its force axes ``(9, 3, 3)`` (rows: the
        link-frame directions of its Fx, Fy, Fz), in the link frame."""
        point, normal, tangent = self.surface(taxel_xy(pitch_m))
        along_v = np.cross(normal, tangent)
        return point, np.stack([tangent, along_v, normal], axis=1)

    def force_in_link(self, force_N: ArrayLike, pitch_m: float) -> F64:
        """``(..., 9, 3)`` taxel forces (patch-frame signs, each taxel's axes) -> the forces
        on the link, ``(..., 9, 3)`` in the link frame (Fz > 0 along -normal)."""
        _, axes = self.taxel_frames(pitch_m)
        axes = axes * np.array([1.0, 1.0, -1.0])[:, None]
        out: F64 = np.einsum("...ka,kab->...kb", np.asarray(force_N, dtype=np.float64), axes)
        return out


@dataclass(frozen=True)
class PatchOnLink:
    """One patch-sample's contact summary in its link's frame."""

    node_id: int
    link: str
    point_m: F64  # (3,) the centre of pressure on the surface
    force_N: F64  # (3,) the net force on the link over the taxels in contact
    normal: F64  # (3,) the surface's outward normal at the centre of pressure
    taxels: tuple[int, ...]  # the taxels in contact
    taxel_points_m: F64  # (len(taxels), 3) their centres
    normal_force_N: float  # net Fz (along each taxel's own normal): the weight in a merge
    area_m2: float
    in_contact: bool


def on_link(node_id: int, placement: PatchPlacement, pitch_m: float, force_N: ArrayLike,
            contact_taxels: ArrayLike, cop_m: ArrayLike, in_contact: bool) -> PatchOnLink:
    """A patch's summary (its taxel forces, the taxels in contact, its patch-frame CoP) in
    its link's frame."""
    mask = np.asarray(contact_taxels, dtype=bool)
    forces = np.asarray(force_N, dtype=np.float64)
    centres, _ = placement.taxel_frames(pitch_m)
    linked = placement.force_in_link(forces, pitch_m)
    point, normal, _ = placement.surface(np.asarray(cop_m, dtype=np.float64))
    return PatchOnLink(node_id, placement.link, point, linked[mask].sum(axis=0), normal,
                       tuple(int(k) for k in np.flatnonzero(mask)), centres[mask],
                       float(forces[mask, 2].sum()), float(mask.sum()) * pitch_m ** 2,
                       in_contact)


@dataclass(frozen=True)
class LinkContact:
    """One contact on one link: the patches of the link that touch one object at once,
    their contact regions adjoining, merged (iCub's ``skinContact``)."""

    link: str
    point_m: F64  # (3,) centre of pressure in the link frame
    force_N: F64  # (3,) net force the object puts on the link (a press: against normal)
    normal: F64  # (3,) unit, outward
    taxels: tuple[tuple[int, int], ...]  # (patch node-ID, taxel) it rests on
    pressure_Pa: float  # net normal force over the taxels' area

    @property
    def patches(self) -> tuple[int, ...]:
        return tuple(sorted({node for node, _ in self.taxels}))

    def to_dict(self) -> dict[str, object]:
        return {"link": self.link, "point_m": self.point_m.tolist(),
                "force_N": self.force_N.tolist(), "normal": self.normal.tolist(),
                "patches": list(self.patches), "taxels": [list(t) for t in self.taxels],
                "pressure_Pa": self.pressure_Pa}


def _adjoin(a: PatchOnLink, b: PatchOnLink, reach_m: float) -> bool:
    gaps = np.linalg.norm(a.taxel_points_m[:, None] - b.taxel_points_m[None], axis=-1)
    return bool(gaps.size) and bool(gaps.min() <= reach_m)


def merge(patches: Sequence[PatchOnLink], pitch_m: float) -> list[LinkContact]:
    """The contacts of one sample: on each link, the patches with a taxel in contact whose
    contact regions adjoin (:data:`ADJOIN_PITCHES`) grouped, and a group reported when one
    of its patches is in contact. In the order of the links' and patches' first mention."""
    touching = [p for p in patches if p.taxels and p.normal_force_N > 0]
    group = list(range(len(touching)))

    def root(i: int) -> int:
        while group[i] != i:
            group[i] = group[group[i]]
            i = group[i]
        return i

    reach = ADJOIN_PITCHES * pitch_m
    for i, a in enumerate(touching):
        for j in range(i):
            b = touching[j]
            if a.link == b.link and _adjoin(a, b, reach):
                group[root(i)] = root(j)
    members: dict[int, list[PatchOnLink]] = {}
    for i, p in enumerate(touching):
        members.setdefault(root(i), []).append(p)
    return [_merged(ps) for ps in members.values() if any(p.in_contact for p in ps)]


def _merged(patches: Sequence[PatchOnLink]) -> LinkContact:
    weights = np.array([p.normal_force_N for p in patches])
    share = weights / weights.sum()
    point = share @ np.stack([p.point_m for p in patches])
    normal = share @ np.stack([p.normal for p in patches])
    normal = normal / max(float(np.linalg.norm(normal)), 1e-300)
    force = np.sum([p.force_N for p in patches], axis=0)
    area = sum(p.area_m2 for p in patches)
    taxels = tuple((p.node_id, k) for p in patches for k in p.taxels)
    return LinkContact(patches[0].link, point, force, normal, taxels,
                       float(weights.sum() / area) if area > 0 else 0.0)
