"""``python -m tests.support.robot_view docs/robot.png``: the example robot (``examples/robot``) at
its zero pose with its patches, and the contact the host reported for a press across the
forearm's two patches (``skin bench robot``'s run), drawn with matplotlib."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import yourdfpy

from canbus.master.hostconfig import load_host_config
from sim.probe import load_probe_scene, run_probe
from skin.benchmarks.contact import train_on
from skin.benchmarks.robot import ROBOT, placements_of, through_host, truth_of
from skin.constants import DEFAULT_CONSTANTS
from skin.contact import ContactParams
from skin.placement import PatchPlacement

PITCH = DEFAULT_CONSTANTS.taxel_pitch_m
COLOURS = {1: "tab:blue", 2: "tab:cyan", 3: "tab:green", 4: "tab:olive"}


def _to_base(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    out: np.ndarray = points @ transform[:3, :3].T + transform[:3, 3]
    return out


def _outline(placement: PatchPlacement) -> np.ndarray:
    half = 1.5 * PITCH
    s = np.linspace(-half, half, 20)
    edge = np.concatenate([np.stack([s, np.full_like(s, -half)], 1),
                           np.stack([np.full_like(s, half), s], 1),
                           np.stack([s[::-1], np.full_like(s, half)], 1),
                           np.stack([np.full_like(s, -half), s[::-1]], 1)])
    points, _, _ = placement.surface(edge)
    return points


def draw(path: str | Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    host = load_host_config(ROBOT / "host.toml")
    probe = load_probe_scene(ROBOT / "probe.toml")
    placements = placements_of(host)
    params = host.contact or ContactParams()
    training = run_probe(probe, placements, 1500, seed=1001)
    decoder = train_on("deconv", training.resistance_ohm, training.force_N)
    run = run_probe(probe, placements, 600, seed=1)
    truth = truth_of(run, probe, placements, params)
    reported = through_host(run, decoder, placements, params)
    k = next(k for k in range(len(run.press)) if run.hold[k] and truth.link[k] == "forearm"
             and len([s for s in truth.shares[k].values() if s >= 0.1]) == 2)
    k += int(np.flatnonzero(run.press == run.press[k]).size // 4)  # into the hold
    (contact,) = [c for c in reported[k] if c.link == "forearm"]

    urdf = yourdfpy.URDF.load(str(ROBOT / "arm.urdf"), load_meshes=False)
    frame = {link: urdf.get_transform(frame_to=link, frame_from="base_link")
             for link in ("upper_arm", "forearm", "palm")}
    fig = plt.figure(figsize=(8, 6))
    ax = fig.add_subplot(projection="3d")
    angle = np.linspace(0, 2 * np.pi, 40)
    for link, radius, length in (("forearm", 0.04, 0.25),):
        for x in np.linspace(0, length, 6):
            ring = np.stack([np.full_like(angle, x), radius * np.sin(angle),
                             radius * np.cos(angle)], 1)
            ax.plot(*_to_base(frame[link], ring).T, color="0.8", lw=0.6)
        for a in angle[::4]:
            line = np.array([[0, radius * np.sin(a), radius * np.cos(a)],
                             [length, radius * np.sin(a), radius * np.cos(a)]])
            ax.plot(*_to_base(frame[link], line).T, color="0.8", lw=0.6)
    box = np.array([[0, -0.05, 0.01], [0.1, -0.05, 0.01], [0.1, 0.05, 0.01], [0, 0.05, 0.01],
                    [0, -0.05, 0.01]])
    ax.plot(*_to_base(frame["palm"], box).T, color="0.5", lw=1)
    for node, placement in placements.items():
        where = frame[placement.link]
        centres, _ = placement.taxel_frames(PITCH)
        ax.plot(*_to_base(where, _outline(placement)).T, color=COLOURS[node], lw=1.5,
                label=f"patch {node} on {placement.link}")
        ax.scatter(*_to_base(where, centres).T, color=COLOURS[node], s=8)
    where = frame["forearm"]
    point = _to_base(where, contact.point_m[None])[0]
    push = where[:3, :3] @ contact.force_N * 0.01  # 10 mm a newton
    ax.quiver(*(point - push), *push, color="red", lw=2)
    ax.scatter(*point, color="red", s=30,
               label=f"contact on forearm, patches {contact.patches}: "
                     f"|F| {np.linalg.norm(contact.force_N):.2f} N")
    ax.scatter(*_to_base(where, truth.point_m[k][None]).T, marker="x", color="k", s=40,
               label="the press's true point")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_xlim(0.3, 0.6)
    ax.set_ylim(-0.07, 0.07)
    ax.set_zlim(0.0, 0.12)
    ax.set_box_aspect((0.3, 0.14, 0.12))
    ax.view_init(elev=25, azim=-60)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title("canskin's example robot at its zero pose: patches, and a contact")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    draw(sys.argv[1] if len(sys.argv) > 1 else "docs/robot.png")
