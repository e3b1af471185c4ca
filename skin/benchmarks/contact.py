"""``skin bench contact``: the contact summary against the simulator's truth, and its cost.

For each scene (``indenter``, ``slide``, ``grasp``, ``stick-slip``): a decoder is trained on
one run of the scene (``deconv`` by default: analytic, then the crosstalk inverse, as
``skin train`` does), another run (another seed) is served as patch TPDO frames through the
host's data plane with force nodes that summarise contact (the host's own code path), and
the :class:`~canbus.master.dataplane.ForceFrame` s' summaries are compared with the truth
of the true loads (:mod:`sim.contact_truth`):

- ``cop_err_mm`` {p50, p95}: distance between the estimated and the true centre of
  pressure, over the samples in contact by the truth (true net Fz at or above the onset
  threshold, with its hysteresis; a true CoP is the Fz-weighted mean of taxel centres, so
  always inside the patch); ``cop_err_mm_from_1N`` the same where the true net normal
  force is at least 1 N (the CoP of a light contact is read noise over a small force);
  ``cop_missing``: the samples in contact without an estimated CoP;
- ``net_fz_err_pct_fs``: RMS error of the net normal force in % of the sensor's full
  scale (``full_scale_force_N``, 5 N: one taxel's, the strict reading), over the same
  samples; ``net_fz_err_pct_fs_stats`` {p50, p95, rms};
- both leave out the samples whose summary says it rests on fewer than 9 valid taxels
  (``partial``: a taxel the decoder flagged, e.g. EXTRAPOLATED), counted in
  ``partial_samples``;
- ``slip_delay_cycles`` {p50, min, max}: for every true slip onset, the cycle at which the
  estimated slip state first holds, from two cycles before it on, minus the onset
  (negative: early); ``slip_missed``: onsets never detected while the truth slipped;
  ``slip_false_alarms``: estimated slip onsets while the truth sticks, other than within
  the two cycles before a true onset;
- ``contact_agreement``: share of samples whose estimated in-contact state is the truth's;
- ``oracle``: the same figures from the oracle decoder (it knows the scene's true
  crosstalk), the floor that read noise sets.

``cost_ratio``: the data plane's time per patch-sample with the summary (and its TPDO)
over without, on ``skin bench dataplane``'s stream (16 patches, ``indenter``, analytic),
each cycle on both, interleaved (:func:`cost`); ``cost.frame_ratio`` the same for the
eighth frame alone.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from canbus.master.contact import PatchContact
from canbus.master.forcenode import CONTACT_TPDO, ForceNode
from canbus.pdo_codec import COB_ID_INVALID, TPDO_COMM
from decoder.oracle import oracle_decode
from decoder.protocol import Decoder
from decoder.registry import create_decoder
from sim import Scene, Simulator, load_scene
from sim.contact_truth import TrueContact, true_contact
from skin.benchmarks.dataplane_rigs import DataPlaneRig, build_stream, published_frames, stream_of
from skin.constants import DEFAULT_CONSTANTS
from skin.contact import ContactParams, PatchGeometry, summarize
from skin.contact_state import track

SCENES = ("indenter", "slide", "grasp", "stick-slip")
TOLERANCE_CYCLES = 2
FIRM_N = 1.0
"""``cop_err_mm_from_1N``: the CoP error where the true net normal force is at least this."""
FULL = {"steps": 6000, "train_steps": 3000, "cost_cycles": 300, "cost_repeats": 7}
QUICK = {"steps": 1500, "train_steps": 1500, "cost_cycles": 100, "cost_repeats": 3}
"""Test cycles per scene, training steps, and the cost run's cycles and repeats."""
F64 = NDArray[np.float64]


@dataclasses.dataclass(frozen=True)
class Estimate:
    """One patch's estimated contact over ``n`` cycles (what the API's frames said)."""

    force_N: F64  # (n, 3)
    cop_m: F64  # (n, 2)
    cop_defined: NDArray[np.bool_]
    in_contact: NDArray[np.bool_]
    slipping: NDArray[np.bool_]
    partial: NDArray[np.bool_]


def scene_params(scene: Scene, base: ContactParams) -> ContactParams:
    """The host's thresholds for a scene: its loads' friction coefficient if they have one
    (what a user would configure), else ``base``'s."""
    frictions = [float(load.params.friction) for load in scene.loads
                 if hasattr(load.params, "friction")]
    return dataclasses.replace(base, friction=max(frictions)) if frictions else base


def train(name: str, scene: Scene, steps: int, seed: int) -> Decoder:
    """Decoder ``name`` fitted on ``steps`` steps of ``scene`` (every patch's samples)."""
    if name == "analytic":
        return create_decoder(name)
    frame = Simulator(scene, seed=seed).run(steps)
    return train_on(name, frame.resistance_ohm, frame.force_N)


def train_on(name: str, resistance_ohm: F64, force_N: F64) -> Decoder:
    """Decoder ``name`` fitted on ``(..., 9, P)`` resistances and their ``(..., 9, 3)``
    true forces (analytic: as it is)."""
    decoder = create_decoder(name)
    if name == "analytic":
        return decoder
    return decoder.fit(resistance_ohm.reshape(-1, 9, resistance_ohm.shape[-1]),
                       force_N.reshape(-1, 9, 3))


def through_dataplane(resistance_ohm: F64, scene: Scene, decoder: Decoder,
                      params: ContactParams) -> list[Estimate]:
    """Every patch's estimate: the resistances served as TPDOs to the data plane."""
    pitch = DEFAULT_CONSTANTS.taxel_pitch_m
    positions = {p.node_id: p.position_m for p in scene.patches}
    index = {k + 1: node for k, node in enumerate(scene.node_ids)}

    def judge(node_id: int) -> PatchContact:
        return PatchContact(PatchGeometry(pitch, positions[index[node_id]]), params)

    stream = stream_of(resistance_ohm, scene.mode)
    frames = published_frames(stream, decoder, judge)
    out = []
    for k in range(len(scene.patches)):
        mine = sorted((f for f in frames if f.patch == k + 1), key=lambda f: f.cycle)
        if len(mine) != resistance_ohm.shape[0]:
            raise RuntimeError(f"patch {k + 1}: {len(mine)} samples of "
                               f"{resistance_ohm.shape[0]} cycles")
        out.append(_estimate([f.contact for f in mine]))
    return out


def _estimate(rows: Sequence[Any]) -> Estimate:
    return Estimate(np.array([c.force_N for c in rows]), np.array([c.cop_m for c in rows]),
                    np.array([c.cop_defined for c in rows]),
                    np.array([c.in_contact for c in rows]),
                    np.array([c.slipping for c in rows]), np.array([c.partial for c in rows]))


def offline(force_N: F64, valid: NDArray[np.bool_], params: ContactParams) -> Estimate:
    """The same summary computed offline (the oracle's forces)."""
    _, b = track(summarize(force_N, valid, params=params), params)
    i = b.instant
    return Estimate(i.force_N, i.cop_m, i.cop_defined, b.in_contact, b.slipping,
                    i.valid_taxels < 9)


def _stats(values: F64) -> dict[str, float | None]:
    if values.size == 0:
        return {"p50": None, "p95": None}
    return {"p50": float(np.percentile(values, 50)), "p95": float(np.percentile(values, 95))}


def slip_figures(slipping: NDArray[np.bool_], truth: TrueContact) -> dict[str, Any]:
    """Each true slip onset's detection delay (``delays``), misses and false alarms."""
    estimated_onsets = np.flatnonzero(np.diff(slipping.astype(np.int8), prepend=0) == 1)
    delays, missed = [], 0
    excused = np.zeros(len(slipping), dtype=bool)
    onsets = truth.slip_onsets.tolist()
    for k0 in onsets:
        end = k0
        while end < len(truth.slip) and truth.slip[end]:
            end += 1
        start = max(k0 - TOLERANCE_CYCLES, 0)
        excused[start:k0] = True
        hit = np.flatnonzero(slipping[start:end])
        if hit.size:
            delays.append(int(start + hit[0] - k0))
        else:
            missed += 1
    false_alarms = sum(1 for k in estimated_onsets.tolist()
                       if not truth.slip[k] and not excused[k])
    return {"slip_onsets": len(onsets), "delays": delays, "slip_missed": missed,
            "slip_false_alarms": false_alarms}


def evaluate(estimates: Sequence[Estimate], truths: Sequence[TrueContact],
             full_scale_N: float) -> dict[str, Any]:
    """The figures of one scene, pooled over its patches (module docstring)."""
    cop, firm, fz, partial, missing, agree, total = [], [], [], 0, 0, 0, 0
    slip: dict[str, Any] = {"slip_onsets": 0, "delays": [], "slip_missed": 0,
                            "slip_false_alarms": 0}
    for est, truth in zip(estimates, truths, strict=True):
        t = truth.batch
        touched = t.in_contact
        whole = touched & ~est.partial
        both = whole & est.cop_defined
        error = 1000 * np.hypot(*(est.cop_m - t.instant.cop_m).T)
        cop.append(error[both])
        firm.append(error[both & (t.instant.force_N[:, 2] >= FIRM_N)])
        missing += int((whole & ~est.cop_defined).sum())
        partial += int((touched & est.partial).sum())
        fz.append(100 * np.abs(est.force_N[whole, 2] - t.instant.force_N[whole, 2])
                  / full_scale_N)
        agree += int((est.in_contact == t.in_contact).sum())
        total += len(t.in_contact)
        for key, value in slip_figures(est.slipping, truth).items():
            slip[key] += value
    fz_all = np.concatenate(fz)
    rms = float(np.sqrt(np.mean(fz_all ** 2))) if fz_all.size else None
    delays = slip.pop("delays")
    return {
        "cop_err_mm": _stats(np.concatenate(cop)), "cop_samples": int(sum(c.size for c in cop)),
        "cop_err_mm_from_1N": _stats(np.concatenate(firm)), "cop_missing": missing,
        "net_fz_err_pct_fs": rms,
        "net_fz_err_pct_fs_stats": {**_stats(fz_all), "rms": rms},
        "partial_samples": partial, "contact_agreement": agree / max(total, 1), **slip,
        "slip_delay_cycles": {"p50": float(np.median(delays)) if delays else None,
                              "min": min(delays) if delays else None,
                              "max": max(delays) if delays else None},
    }


def bench_scene(name: str, *, steps: int, train_steps: int, decoder_name: str,
                base: ContactParams, seed: int = 1) -> dict[str, Any]:
    """Every figure of one scene."""
    scene = load_scene(name)
    params = scene_params(scene, base)
    decoder = train(decoder_name, scene, train_steps, seed + 1000)
    frame = Simulator(scene, seed=seed).run(steps)
    truths = true_contact(frame, scene, params)
    full_scale = DEFAULT_CONSTANTS.full_scale_force_N
    result = evaluate(through_dataplane(frame.resistance_ohm, scene, decoder, params), truths,
                      full_scale)
    oracle = []
    for k in range(len(scene.patches)):
        decoded = oracle_decode(frame.resistance_ohm[:, k], scene.crosstalk_matrix())
        oracle.append(offline(decoded.force_N, decoded.valid, params))
    floor = evaluate(oracle, truths, full_scale)
    return {"scene": name, "patches": len(scene.patches), "cycles": steps,
            "decoder": decoder_name, "params": dataclasses.asdict(params), **result,
            "oracle": {key: floor[key] for key in ("cop_err_mm", "cop_err_mm_from_1N",
                                                   "net_fz_err_pct_fs",
                                                   "net_fz_err_pct_fs_stats",
                                                   "slip_delay_cycles", "slip_false_alarms")}}


def cost(patches: int = 16, cycles: int = 300, repeats: int = 5) -> dict[str, Any]:
    """The data plane's time per patch-sample with and without the contact summary, on
    ``skin bench dataplane``'s stream (``patches`` patches, indenter, analytic decoder);
    and with the eighth frame alone (``frame_only``: force nodes without a contact judge
    whose TPDO 8 a master made valid: it carries "no summary", nothing is computed).

    Each SYNC cycle (every patch's TPDOs in, one publishing batch out) runs on the data
    planes one after the other, in turning order, ``repeats`` times over the stream;
    a cycle's time is the CPU time of this thread (``time.thread_time``: the time others'
    work takes the core away is not counted), the 20th percentile of its runs (what others
    still add, through the caches, only ever adds), the per-sample time the sum over cycles
    over the samples.
    """
    stream = build_stream(patches, cycles, "xyz")
    decoder = create_decoder("analytic")
    rigs = {"with": DataPlaneRig(stream, decoder, contact=lambda node_id: PatchContact()),
            "without": DataPlaneRig(stream, decoder, contact=None),
            "frame_only": DataPlaneRig(stream, decoder, contact=None)}
    for node in rigs["frame_only"].force_nodes:
        _validate_tpdo8(node)
    times = {key: np.zeros((repeats, cycles)) for key in rigs}
    try:
        for rig in rigs.values():  # first runs: layouts, caches, the decoder's first call
            rig.run(stream)
        for rep in range(repeats):
            for rig in rigs.values():
                rig.sink.sent.clear()
            for k, frames in enumerate(stream.frames):
                turn = (rep + k) % len(rigs)
                order = list(rigs)[turn:] + list(rigs)[:turn]
                for key in order:
                    times[key][rep, k] = _cycle(rigs[key], k, stream.sync_times[k], frames)
        frames_out = {key: len(rig.sink.sent) for key, rig in rigs.items()}
    finally:
        for rig in rigs.values():
            rig.close()
    per_sample = {key: float(np.percentile(t, 20, axis=0).sum()) / (patches * cycles)
                  for key, t in times.items()}
    return {"patches": patches, "cycles": cycles, "repeats": repeats,
            "with_us_per_sample": 1e6 * per_sample["with"],
            "without_us_per_sample": 1e6 * per_sample["without"],
            "frame_only_us_per_sample": 1e6 * per_sample["frame_only"],
            "frames_out_with": frames_out["with"], "frames_out_without": frames_out["without"],
            "frame_ratio": per_sample["frame_only"] / per_sample["without"],
            "cost_ratio": per_sample["with"] / per_sample["without"]}


def _validate_tpdo8(node: ForceNode) -> None:
    """What a master's SDO write of 0x1807:01 does: the contact TPDO valid again."""
    index = TPDO_COMM + CONTACT_TPDO - 1
    cob = int(node.store.value(index, 1)) & ~COB_ID_INVALID
    node.store.set_data(index, 1, cob.to_bytes(4, "little"))


def _cycle(rig: DataPlaneRig, k: int, sync_time: float, frames: Sequence[Any]) -> float:
    """Seconds for one SYNC cycle: open it, take every frame, publish the batch."""
    plane = rig.plane
    receive = plane.on_message_received
    start = time.thread_time()
    plane.on_sync(k + 1, 0, sync_time)
    for msg in frames:
        receive(msg)
    plane.publish_pending()
    return time.thread_time() - start


def run_contact_benchmark(*, quick: bool = False, decoder: str = "deconv",
                          params: ContactParams | None = None, scenes: Sequence[str] = SCENES,
                          stage: Callable[[str], None] = lambda label: None) -> dict[str, Any]:
    """Every figure of ``skin bench contact``."""
    sizes = QUICK if quick else FULL
    base = params or ContactParams()
    out: dict[str, Any] = {"decoder": decoder, "full_scale_N":
                           DEFAULT_CONSTANTS.full_scale_force_N,
                           "tolerance_cycles": TOLERANCE_CYCLES, "scenes": {}}
    for name in scenes:
        stage(f"contact on {name}")
        out["scenes"][name] = bench_scene(name, steps=sizes["steps"],
                                          train_steps=sizes["train_steps"],
                                          decoder_name=decoder, base=base)
    stage("cost in the data plane")
    figures = cost(cycles=sizes["cost_cycles"], repeats=sizes["cost_repeats"])
    out["cost"] = figures
    out["cost_ratio"] = figures["cost_ratio"]
    return out
