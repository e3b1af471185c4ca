"""``skin bench robot``: contacts on the example robot against the probe's truth.

The example robot (``examples/robot``: ``arm.urdf``, ``host.toml``, ``probe.toml``): four
patches placed on its forearm (curved) and palm (flat) by the host's config; the probe
scene presses a sphere at known points of their skin (:mod:`sim.probe`). A decoder
(``deconv`` by default) is trained on one run of the scene, another run (another seed) is
served as patch TPDOs through the host's data plane whose force nodes summarise contact
and know each patch's placement (the host's own path), and each cycle's robot-wide contact
list (:func:`canbus.master.robot.contacts_of`) is compared with the press:

- ``contact_point_err_mm`` {p50, p95}: distance, in the link's frame, between the press's
  point and the reported contact on that link nearest to it, over the samples the probe
  holds its press (``hold``); ``contact_point_err_mm_all`` the same over every sample in
  contact by the truth (ramps included: a light touch's point is the taxels' resolution);
- ``contact_force_err_pct_fs`` {p50, p95, rms}: |reported − true net force| (3-vectors in
  the link frame; the truth the true taxel forces along each taxel's axes) in % of one
  taxel's full scale (5 N), over the held samples;
- ``missed_samples``: samples in contact by the truth with no contact reported on the link;
- ``links``: the links the truth touches, and ``links_reported``: those with a contact;
- ``cross_patch_presses`` {count, merged}: presses whose true load at full depth puts at
  least 10 % of its normal force on each of two patches, and how many of them were
  reported as one contact resting on both patches in every held sample.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from canbus.master.channel import ForceFrame
from canbus.master.contact import PatchContact
from canbus.master.hostconfig import HostConfig, load_host_config
from canbus.master.robot import contacts_of
from decoder.protocol import Decoder
from sim.probe import ProbeRun, ProbeScene, load_probe_scene, run_probe
from skin.benchmarks.contact import train_on
from skin.benchmarks.dataplane_rigs import published_frames, stream_of
from skin.constants import DEFAULT_CONSTANTS
from skin.contact import ContactParams, PatchGeometry
from skin.errors import ConfigError
from skin.placement import LinkContact, PatchPlacement

ROBOT = Path(__file__).resolve().parents[2] / "examples" / "robot"
"""The example robot of a source checkout (it is not installed with the wheel)."""
CROSS_SHARE = 0.1
FULL = {"steps": 6000, "train_steps": 3000}
QUICK = {"steps": 1500, "train_steps": 1500}
F64 = NDArray[np.float64]


@dataclasses.dataclass(frozen=True)
class Truth:
    link: list[str]  # (n,) the press's link
    point_m: F64  # (n, 3) the press's point
    force_N: F64  # (n, 3) the true net force in the link frame
    in_contact: NDArray[np.bool_]  # (n,) the true net normal force at or above onset_N
    shares: list[dict[int, float]]  # (n,) each patch's share of the true normal force


def truth_of(run: ProbeRun, scene: ProbeScene, placements: Mapping[int, PatchPlacement],
             params: ContactParams) -> Truth:
    pitch = DEFAULT_CONSTANTS.taxel_pitch_m
    n = len(run.press)
    force = np.zeros((n, 3))
    normal = np.zeros((n, len(run.node_ids)))
    for i, node in enumerate(run.node_ids):
        force += placements[node].force_in_link(run.force_N[:, i], pitch).sum(axis=1)
        normal[:, i] = run.force_N[:, i, :, 2].sum(axis=1)
    total = normal.sum(axis=1)
    shares = [{node: float(normal[k, i] / total[k]) for i, node in enumerate(run.node_ids)
               if total[k] > 0 and normal[k, i] > 0} for k in range(n)]
    presses = [scene.presses[j] for j in run.press.tolist()]
    return Truth([p.link for p in presses], np.array([p.point_m for p in presses]), force,
                 total >= params.onset_N, shares)


def through_host(run: ProbeRun, decoder: Decoder, placements: Mapping[int, PatchPlacement],
                 params: ContactParams) -> list[list[LinkContact]]:
    """Each cycle's robot-wide contact list, the run served to the host's data plane."""
    pitch = DEFAULT_CONSTANTS.taxel_pitch_m
    nodes = list(run.node_ids)
    if nodes != list(range(1, len(nodes) + 1)):
        raise ValueError(f"the bench serves node-IDs 1..N, the config has {nodes}")

    def judge(node_id: int) -> PatchContact:
        return PatchContact(PatchGeometry(pitch), params, placements[node_id])

    stream = stream_of(run.resistance_ohm, "xyz")
    frames = published_frames(stream, decoder, judge)
    by_cycle: dict[int, list[ForceFrame]] = {}
    for frame in frames:
        by_cycle.setdefault(frame.cycle, []).append(frame)
    return [contacts_of(by_cycle.get(k + 1, [])) for k in range(len(run.press))]


def _stats(values: list[float]) -> dict[str, float | None]:
    if not values:
        return {"p50": None, "p95": None}
    a = np.asarray(values)
    return {"p50": float(np.percentile(a, 50)), "p95": float(np.percentile(a, 95))}


def evaluate(run: ProbeRun, truth: Truth, reported: list[list[LinkContact]],
             full_scale_N: float) -> dict[str, Any]:
    """The figures (module docstring)."""
    held, every, force_err, missed = [], [], [], 0
    reported_links: set[str] = set()
    for k, contacts in enumerate(reported):
        reported_links.update(c.link for c in contacts)
        if not truth.in_contact[k]:
            continue
        mine = [c for c in contacts if c.link == truth.link[k]]
        if not mine:
            missed += 1
            continue
        gaps = [float(np.linalg.norm(c.point_m - truth.point_m[k])) for c in mine]
        best = mine[int(np.argmin(gaps))]
        every.append(1e3 * min(gaps))
        if run.hold[k]:
            held.append(1e3 * min(gaps))
            force_err.append(100 * float(np.linalg.norm(best.force_N - truth.force_N[k]))
                             / full_scale_N)
    count, merged = _cross_presses(run, truth, reported)
    errors = np.asarray(force_err)
    return {
        "contact_point_err_mm": _stats(held), "contact_point_err_mm_all": _stats(every),
        "held_samples": len(held), "contact_samples": len(every), "missed_samples": missed,
        "contact_force_err_pct_fs": {**_stats(force_err), "rms": float(np.sqrt(np.mean(
            errors ** 2))) if errors.size else None},
        "links": sorted({truth.link[k] for k in np.flatnonzero(truth.in_contact).tolist()}),
        "links_reported": sorted(reported_links),
        "cross_patch_presses": {"count": count, "merged": merged},
    }


def _cross_presses(run: ProbeRun, truth: Truth, reported: list[list[LinkContact]]
                   ) -> tuple[int, int]:
    """Presses across two patches (by the truth at full depth), and those reported as one
    contact on both in every held sample."""
    starts = [*np.flatnonzero(np.diff(run.press, prepend=-1) != 0).tolist(), len(run.press)]
    count = merged = 0
    for a, b in itertools.pairwise(starts):
        hold = [k for k in range(a, b) if run.hold[k]]
        if not hold:
            continue
        across = {node for node, share in truth.shares[hold[len(hold) // 2]].items()
                  if share >= CROSS_SHARE}
        if len(across) < 2:
            continue
        count += 1
        link = truth.link[hold[0]]
        one = all(len(on := [c for c in reported[k] if c.link == link]) == 1
                  and across <= set(on[0].patches) for k in hold)
        merged += one
    return count, merged


def placements_of(config: HostConfig) -> dict[int, PatchPlacement]:
    out = {p.node_id: p.placement for p in config.patches if p.placement is not None}
    if not out:
        raise ValueError(f"{config.source}: no patch is placed on a link")
    return out


def run_robot_benchmark(*, quick: bool = False, decoder: str = "deconv",
                        config: str | Path = ROBOT / "host.toml",
                        scene: str | Path = ROBOT / "probe.toml", seed: int = 1,
                        stage: Callable[[str], None] = lambda label: None) -> dict[str, Any]:
    """Every figure of ``skin bench robot``."""
    sizes = QUICK if quick else FULL
    if Path(config) == ROBOT / "host.toml" and not ROBOT.is_dir():
        raise ConfigError("skin bench robot", "runs the example robot of a source checkout "
                          f"(examples/robot), not found at {ROBOT}")
    host = load_host_config(config)
    probe = load_probe_scene(scene)
    placements = placements_of(host)
    params = host.contact or ContactParams()
    stage(f"training {decoder} on the probe scene")
    training = run_probe(probe, placements, sizes["train_steps"], seed=seed + 1000)
    fitted = train_on(decoder, training.resistance_ohm, training.force_N)
    stage("the probe served to the host")
    run = run_probe(probe, placements, sizes["steps"], seed=seed)
    truth = truth_of(run, probe, placements, params)
    reported = through_host(run, fitted, placements, params)
    full_scale = DEFAULT_CONSTANTS.full_scale_force_N
    return {"config": str(config), "scene": str(scene), "decoder": decoder,
            "cycles": sizes["steps"], "full_scale_N": full_scale,
            **evaluate(run, truth, reported, full_scale)}
