"""A dataset from a bus recording and reference forces: what ``skin dataset from-recording``
writes (docs/calibrate.md).

Each patch's samples come from :func:`canbus.offline.recorded.read_patch_samples` (the
data plane's answer rules), the reference from :func:`skin.reference.read_reference`,
and they are joined by :func:`canbus.tools.join.join` on one clock offset for every
patch. A dataset row is one SYNC at which every chosen patch has a complete sample with
every taxel read, joined to a reference sample; everything else is counted and left out,
never filled in. The file is the one ``skin sim dataset`` writes (:mod:`skin.dataset`).
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from canbus.offline.recorded import PatchSamples, RecordedSamples, read_patch_samples
from canbus.tools.join import Join, Series, default_tolerance_s, join
from decoder.reasons import Reason
from skin.constants import DEFAULT_CONSTANTS, TAXELS_PER_PATCH
from skin.dataset import Dataset
from skin.errors import ConfigError
from skin.reference import ReferenceSamples, read_reference

JOIN_MODES = ("sync", "time")


@dataclass(frozen=True)
class JoinChoice:
    """How to join: ``by`` None chooses "sync" when both sides carry SYNC counters."""

    by: str | None = None
    tolerance_ms: float | None = None
    clock_offset_ms: float | None = None


@dataclass(frozen=True)
class RecordedDataset:
    dataset: Dataset
    cycles: NDArray[np.int64]  # (rows,) the listen-only host's SYNC cycle of each row
    report: dict[str, Any]  # counts per patch, the join, the mapping (JSON-able)
    recorded: RecordedSamples
    reference: ReferenceSamples


def dataset_from_recording(recording: str | os.PathLike[str],
                           reference: str | os.PathLike[str], *,
                           nodes: tuple[int, ...] | None = None, mapping: str | None = None,
                           how: JoinChoice = JoinChoice(), sync_window_ms: float | None = None,
                           heartbeat_ms: int | None = None,
                           answer_order: str = "cob-id") -> RecordedDataset:
    """Read, join and count (module docstring); raises ReferenceFileError, RecordingError
    or ConfigError with one line naming the file and row, frame or option."""
    ref = read_reference(reference)
    if nodes is None:
        nodes = ref.nodes
        if not nodes:
            raise ConfigError("--reference", f"{ref.source}: no complete reference sample")
    else:
        absent = [n for n in nodes if n not in ref.nodes]
        if absent:
            raise ConfigError("--node", f"{ref.source} has no complete sample of patch "
                              f"{absent[0]}")
    recorded = read_patch_samples(recording, nodes, mapping=mapping,
                                  sync_window_ms=sync_window_ms, heartbeat_ms=heartbeat_ms,
                                  answer_order=answer_order)
    pillars = {p.mapping.pillars for p in recorded.patches.values()}
    if len(pillars) > 1:
        raise ConfigError("--node", "the patches are read in z and in xyz mode: make one "
                          "dataset per mode (--node)")
    period_s = recorded.facts.sync_period_s
    assert period_s is not None, "read_patch_samples needs the SYNC period"
    by = _join_mode(how.by, ref, recorded)
    tolerance_s = None if how.tolerance_ms is None else how.tolerance_ms / 1000.0
    offset_s = None if how.clock_offset_ms is None else how.clock_offset_ms / 1000.0
    series = {n: (_recorded_series(p), _reference_series(ref, n)) for n, p in
              recorded.patches.items()}
    estimated = None
    if not any(p.usable.any() for p in recorded.patches.values()):
        joins = {n: _nothing(by, period_s, tolerance_s, offset_s) for n in nodes}
    else:
        if offset_s is None and ref.has_time:  # one reference clock: one offset for all
            first = max(series, key=lambda n: int(np.isfinite(series[n][0].load).sum()))
            estimated = join(*series[first], by=by, period_s=period_s, tolerance_s=tolerance_s)
            offset_s = estimated.clock_offset_s
        joins = {n: join(*series[n], by=by, period_s=period_s, tolerance_s=tolerance_s,
                         clock_offset_s=offset_s) for n in nodes}
    rows = _rows(recorded, joins, nodes)
    p, count = pillars.pop(), len(rows[nodes[0]])
    r = np.zeros((count, len(nodes), TAXELS_PER_PATCH, p))
    f = np.zeros((count, len(nodes), TAXELS_PER_PATCH, 3))
    for j, node in enumerate(nodes):
        samples, idx = recorded.patches[node], ref.of_node(node)
        pairs = dict(zip(joins[node].recorded.tolist(), joins[node].reference.tolist(),
                         strict=True))
        for i, k_rec in enumerate(rows[node]):
            r[i, j] = samples.resistance_ohm[k_rec]
            f[i, j] = ref.force_N[idx[pairs[k_rec]]]
    report = _report(recorded, ref, joins, rows, nodes, estimated)
    first_patch = recorded.patches[nodes[0]]
    constants = dataclasses.replace(DEFAULT_CONSTANTS, resistance_lsb_ohm=first_patch.lsb_ohm)
    meta = {"scene": None, "seed": None, "effects": [], "constants": constants.to_dict(),
            "mode": first_patch.mapping.mode, "source": "recording",
            "recording": os.fspath(recording), "reference": os.fspath(reference),
            "node_ids": list(nodes), "join": report["join"], "mapping": report["mapping"],
            "samples": report["samples"]}
    cycles = recorded.patches[nodes[0]].cycle[rows[nodes[0]]]
    return RecordedDataset(Dataset(r, f, meta), cycles, report, recorded, ref)


def _nothing(by: str, period_s: float, tolerance_s: float | None,
             offset_s: float | None) -> Join:
    """No pairs: no patch has a usable sample, so there is nothing to join (or to estimate a
    clock offset from)."""
    empty = np.zeros(0, dtype=np.intp)
    tol = default_tolerance_s(by, period_s) if tolerance_s is None else tolerance_s
    return Join(by, tol, math.nan if offset_s is None else offset_s, offset_s is None, None,
                empty, empty)


def _join_mode(by: str | None, ref: ReferenceSamples, recorded: RecordedSamples) -> str:
    counters = all(bool(np.all(p.sync_counter != 0)) for p in recorded.patches.values())
    if by is None:
        return "sync" if ref.has_sync and counters else "time"
    if by not in JOIN_MODES:
        raise ConfigError("--join", f"must be one of {', '.join(JOIN_MODES)}, got {by!r}")
    if by == "sync" and not ref.has_sync:
        raise ConfigError("--join", f"{ref.source} names no SYNC counter (no sync column)")
    if by == "sync" and not counters:
        raise ConfigError("--join", f"{recorded.source}: the SYNCs carry no counter")
    if by == "time" and not ref.has_time:
        raise ConfigError("--join", f"{ref.source} has no time_s column")
    return by


def _recorded_series(samples: PatchSamples) -> Series:
    """Times, counters and the load signal: the sum over taxels of -(R_z / median - 1)."""
    z = samples.resistance_ohm[:, :, 0]
    load = np.full(z.shape[0], np.nan)
    usable = samples.usable
    if usable.any():
        rest = np.median(z[usable], axis=0)
        load[usable] = -np.sum(z[usable] / rest - 1.0, axis=1)
    return Series(samples.time_s, samples.sync_counter, load)


def _reference_series(ref: ReferenceSamples, node: int) -> Series:
    idx = ref.of_node(node)
    return Series(ref.time_s[idx], ref.sync[idx], ref.force_N[idx, :, 2].sum(axis=1))


def _rows(recorded: RecordedSamples, joins: dict[int, Join], nodes: tuple[int, ...]
          ) -> dict[int, list[int]]:
    """Per patch, the recorded sample of each dataset row: the cycles at which every patch
    has a usable, joined sample, in cycle order."""
    usable_cycles: dict[int, dict[int, int]] = {}
    for node in nodes:
        samples = recorded.patches[node]
        joined = joins[node].recorded
        ok = joined[samples.usable[joined]]
        usable_cycles[node] = {int(samples.cycle[k]): int(k) for k in ok}
    common = sorted(set.intersection(*(set(c) for c in usable_cycles.values())))
    return {node: [usable_cycles[node][c] for c in common] for node in nodes}


def _report(recorded: RecordedSamples, ref: ReferenceSamples, joins: dict[int, Join],
            rows: dict[int, list[int]], nodes: tuple[int, ...],
            estimate: Join | None) -> dict[str, Any]:
    per_patch: dict[str, Any] = {}
    for node in nodes:
        samples, joined = recorded.patches[node], joins[node]
        usable = samples.usable
        missing = np.all(samples.reason == Reason.MISSING, axis=1)
        matched = np.zeros(samples.cycle.size, dtype=bool)
        matched[joined.recorded] = True
        n_ref = int(ref.of_node(node).size)
        per_patch[str(node)] = {
            "recording": samples.counts(),
            "reference": {"samples": n_ref, "incomplete": ref.incomplete.get(node, 0)},
            "joined": int(joined.recorded.size),
            "joined_but_incomplete": int((matched & ~samples.complete & ~missing).sum()),
            "joined_but_unanswered": int((matched & ~samples.complete & missing).sum()),
            "joined_but_faulty": int((matched & samples.complete & ~usable).sum()),
            "unjoined_reference": n_ref - int(joined.recorded.size),
            "unjoined_recording": int((usable & ~matched).sum()),
            "left_out_other_patch": int((matched & usable).sum()) - len(rows[node]),
            "written": len(rows[node]),
        }
    first = joins[nodes[0]]
    found = estimate or first
    offset = first.clock_offset_s
    how = {"by": first.by, "tolerance_ms": 1000.0 * first.tolerance_s,
           "clock_offset_ms": 1000.0 * offset if math.isfinite(offset) else None,
           "clock_offset_estimated": found.offset_estimated, "correlation": found.correlation}
    mapping = {str(n): {"mapping": recorded.patches[n].mapping.name,
                        "from": recorded.patches[n].mapping.source} for n in nodes}
    config = recorded.config
    return {"samples": len(next(iter(rows.values()))), "patches": per_patch, "join": how,
            "mapping": mapping, "sync_period_ms": config.sync_period_ms,
            "sync_window_ms": config.sync_window_ms, "heartbeat_ms": config.heartbeat_ms,
            "recording_frames": recorded.facts.frames,
            "reference_rows": ref.rows, "reference_form": ref.form}

