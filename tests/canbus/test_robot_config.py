"""Patches placed on a robot's links by the host config (canbus.master.robotconfig): from a
pose in the config or a frame of the robot's URDF; a bad link, frame or pose is one line
naming the field and nothing starts; a patch without a link is as before."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yourdfpy
from numpy.testing import assert_allclose

from canbus.master.hostconfig import load_host_config
from skin.cli import main
from skin.errors import ConfigError
from skin.placement import Pose

ROBOT = Path(__file__).resolve().parents[2] / "examples" / "robot"


def test_the_example_robot_places_its_patches_as_its_urdf_says() -> None:
    config = load_host_config(ROBOT / "host.toml")
    placed = {p.node_id: p.placement for p in config.patches}
    urdf = yourdfpy.URDF.load(str(ROBOT / "arm.urdf"), load_meshes=False)
    for node, frame in ((1, "forearm_skin_1"), (2, "forearm_skin_2")):
        placement = placed[node]
        assert placement is not None
        assert (placement.link, placement.frame, placement.radius_m) == ("forearm", frame, 0.04)
        expected = urdf.get_transform(frame_to=frame, frame_from="forearm")
        assert_allclose(placement.pose.matrix, expected[:3, :3], atol=1e-12)  # parsed decimals
        assert_allclose(placement.pose.vector, expected[:3, 3], atol=1e-12)
    palm = placed[4]
    assert palm is not None and palm.link == "palm" and palm.radius_m is None
    assert palm.pose == Pose((0.05, 0.0225, 0.01))  # exact: the config's decimals, no rotation
    for node in (1, 2):  # the forearm patches' skin lies on the forearm, 40 mm from its axis
        centres, _ = placed[node].taxel_frames(0.015)  # type: ignore[union-attr]
        assert_allclose(np.hypot(centres[:, 1], centres[:, 2]), 0.04, atol=1e-5)


def test_a_patch_without_a_link_is_placed_nowhere(tmp_path: Path) -> None:
    path = tmp_path / "host.toml"
    path.write_text("[[patches]]\nnode_id = 1\nposition_m = [0.1, 0.0]\n")
    (patch,) = load_host_config(path).patches
    assert patch.placement is None and patch.position_m == (0.1, 0.0)


def _robot_config(tmp_path: Path, patch: str, robot: str = '[robot]\nurdf = "arm.urdf"\n'
                  ) -> Path:
    shutil.copy(ROBOT / "arm.urdf", tmp_path / "arm.urdf")
    path = tmp_path / "host.toml"
    path.write_text(f"{robot}[[patches]]\nnode_id = 1\n{patch}")
    return path


@pytest.mark.parametrize(("patch", "robot", "expected"), [
    ('link = "forarm"\nframe = "forearm_skin_1"\n', None,
     "patches[0].link: no link 'forarm' in arm.urdf"),
    ('link = "forearm"\nframe = "forearm_skin_9"\n', None,
     "patches[0].frame: no frame 'forearm_skin_9' in arm.urdf"),
    ('link = "palm"\nframe = "forearm_skin_1"\n', None,
     "patches[0].frame: 'forearm_skin_1' is not on link 'palm' in arm.urdf"),
    ('link = "upper_arm"\nframe = "forearm_skin_1"\n', None,
     "patches[0].frame: 'forearm_skin_1' moves on link 'upper_arm': joint 'elbow' between "
     "them is revolute"),
    ('link = "palm"\npose = { xyz_m = [0.0, nan, 0.0] }\n', None,
     "patches[0].pose.xyz_m[1]: must be a finite number"),
    ('link = "palm"\npose = { rpy_deg = [0.0, 0.0, inf] }\n', None,
     "patches[0].pose.rpy_deg[2]: must be a finite number"),
    ('link = "palm"\npose = { xyz_m = [0.0, 0.0] }\n', None,
     "patches[0].pose.xyz_m: must be [x, y, z]"),
    ('link = "palm"\npose = { xyz = [0.0, 0.0, 0.0] }\n', None,
     "patches[0].pose.xyz: unknown key"),
    ('link = "palm"\nradius_m = -0.04\n', None, "patches[0].radius_m: must be > 0"),
    ('frame = "forearm_skin_1"\n', None, "patches[0].link: missing"),
    ('link = "forearm"\nframe = "forearm_skin_1"\n', "", "patches[0].frame: needs the robot's "
     "URDF"),
    ('link = "palm"\n', '[robot]\nurdf = "no-such.urdf"\n', "robot.urdf: no such file"),
])
def test_a_bad_placement_is_one_line_naming_the_field(
        tmp_path: Path, patch: str, robot: str | None, expected: str) -> None:
    path = _robot_config(tmp_path, patch, *(() if robot is None else (robot,)))
    with pytest.raises(ConfigError) as info:
        load_host_config(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.removeprefix(f"{path}: ").startswith(expected), message


def test_a_urdf_that_is_not_one_is_one_line(tmp_path: Path) -> None:
    path = _robot_config(tmp_path, 'link = "palm"\n')
    (tmp_path / "arm.urdf").write_text("<robot name='x'><link></robot")
    with pytest.raises(ConfigError) as info:
        load_host_config(path)
    assert str(info.value).startswith(f"{path}: robot.urdf: arm.urdf: not a URDF")
    assert "\n" not in str(info.value)


def test_skin_run_with_a_bad_placement_starts_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _robot_config(tmp_path, 'link = "forearm"\nframe = "forearm_skin_9"\n')
    assert main(["run", str(path), "-i", "virtual", "-c", "never-opened"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "patches[0].frame: no frame 'forearm_skin_9'" in err
