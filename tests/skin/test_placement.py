"""Patches on links (skin.placement): the geometry a controller relies on, whatever the
poses: a rigid motion of the link's frame moves the contact with it, a patch's surface maps
back to its own coordinates, and adjoining patches' contacts on one link are one contact."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from skin.contact import summarize, taxel_xy
from skin.placement import PatchOnLink, PatchPlacement, Pose, merge, on_link, rpy_matrix

PITCH = 0.015
angles = st.floats(-180.0, 180.0)
lengths = st.floats(-0.5, 0.5)
poses = st.builds(lambda xyz, rpy: Pose.from_xyz_rpy(xyz, rpy),
                  st.tuples(lengths, lengths, lengths), st.tuples(angles, angles, angles))
radii = st.one_of(st.none(), st.floats(0.02, 1.0))
taxel_forces = st.lists(st.tuples(st.floats(-2, 2), st.floats(-2, 2), st.floats(0, 5)),
                        min_size=9, max_size=9)


def _summary_on_link(placement: PatchPlacement, forces: np.ndarray) -> PatchOnLink:
    c = summarize(forces[None], np.ones((1, 9), dtype=bool))
    return on_link(1, placement, PITCH, forces, c.contact_taxels[0], c.cop_m[0], True)


@settings(max_examples=200)
@given(pose=poses, motion=poses, radius=radii, forces=taxel_forces)
def test_a_rigid_motion_of_the_link_moves_the_contact_with_it(
        pose: Pose, motion: Pose, radius: float | None, forces: list[tuple[float, ...]]
) -> None:
    f = np.array(forces)
    here = _summary_on_link(PatchPlacement("l", pose, radius), f)
    moved = _summary_on_link(PatchPlacement("l", pose.then(motion), radius), f)
    rot, t = motion.matrix, motion.vector
    assert_allclose(moved.point_m, rot @ here.point_m + t, atol=1e-12)  # metres: float64 ulps
    assert_allclose(moved.force_N, rot @ here.force_N, atol=1e-12)
    assert_allclose(moved.normal, rot @ here.normal, atol=1e-12)
    assert moved.taxels == here.taxels
    assert_allclose(np.linalg.norm(here.normal), 1.0, atol=1e-12)


@settings(max_examples=200)
@given(pose=poses, radius=radii, u=st.floats(-0.05, 0.05), v=st.floats(-0.05, 0.05))
def test_a_point_of_the_skin_maps_back_to_its_patch_coordinates(
        pose: Pose, radius: float | None, u: float, v: float) -> None:
    placement = PatchPlacement("l", pose, radius)
    point, normal, tangent = placement.surface([u, v])
    uv, height = placement.to_patch(point)
    assert_allclose(uv, [u, v], atol=1e-12)
    assert abs(height) < 1e-12
    assert abs(normal @ tangent) < 1e-12  # the force axes of a taxel are orthonormal
    _, axes = placement.taxel_frames(PITCH)
    assert_allclose(axes @ axes.transpose(0, 2, 1), np.broadcast_to(np.eye(3), (9, 3, 3)),
                    atol=1e-12)
    assert_allclose(np.linalg.det(axes), 1.0, atol=1e-12)  # right-handed


def test_a_flat_patch_at_the_link_origin_is_its_patch_frame() -> None:
    f = np.zeros((9, 3))
    f[5] = [0.3, -0.2, 2.0]
    f[4] = [0.0, 0.0, 1.0]
    c = summarize(f[None], np.ones((1, 9), dtype=bool))
    got = _summary_on_link(PatchPlacement("palm"), f)
    assert_allclose(got.point_m, [*c.cop_m[0], 0.0], atol=1e-15)
    assert_allclose(got.force_N, c.force_N[0] * [1, 1, -1], atol=1e-15)  # a press: into it
    assert_allclose(got.normal, [0.0, 0.0, 1.0])


def test_urdf_rpy_is_yaw_pitch_roll_about_fixed_axes() -> None:
    assert_allclose(rpy_matrix([0, 0, np.pi / 2]) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    assert_allclose(rpy_matrix([np.pi / 2, 0, np.pi / 2]) @ [0, 1, 0], [0, 0, 1], atol=1e-15)


def _pressed(node: int, placement: PatchPlacement, taxels: list[int]) -> PatchOnLink:
    f = np.zeros((9, 3))
    f[taxels, 2] = 1.0
    c = summarize(f[None], np.ones((1, 9), dtype=bool))
    return on_link(node, placement, PITCH, f, c.contact_taxels[0], c.cop_m[0], True)


def test_adjoining_patches_of_one_link_touched_at_once_are_one_contact() -> None:
    left = PatchPlacement("palm", Pose((-0.0225, 0.0, 0.0)))
    right = PatchPlacement("palm", Pose((0.0225, 0.0, 0.0)))
    a, b = _pressed(3, left, [5]), _pressed(4, right, [3])  # the border taxels, 15 mm apart
    (one,) = merge([a, b], PITCH)
    assert one.patches == (3, 4) and one.taxels == ((3, 5), (4, 3))
    assert_allclose(one.point_m, [0.0, 0.0, 0.0], atol=1e-15)  # between the two, equal forces
    assert_allclose(one.force_N, [0.0, 0.0, -2.0])
    far = _pressed(4, right, [5])  # 45 mm from patch 3's contact: another object
    assert len(merge([a, far], PITCH)) == 2
    other_link = _pressed(4, PatchPlacement("forearm", right.pose), [3])
    assert [c.link for c in merge([a, other_link], PITCH)] == ["palm", "forearm"]


def test_a_curved_patch_wraps_its_taxels_round_its_cylinder() -> None:
    radius = 0.04
    placement = PatchPlacement("forearm", Pose((0.0, 0.0, radius)), radius)
    centres, axes = placement.taxel_frames(PITCH)
    assert_allclose(np.hypot(centres[:, 0], centres[:, 2]), radius, atol=1e-15)  # on the skin
    assert_allclose(axes[:, 2], centres * [1, 0, 1] / radius, atol=1e-15)  # normals radial
    assert_allclose(taxel_xy(PITCH)[:, 1], centres[:, 1], atol=1e-15)  # y along the axis
