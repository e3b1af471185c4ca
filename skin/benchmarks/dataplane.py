# canopen 2.4 ships py.typed but leaves many methods unannotated.
# mypy: disable-error-code="no-untyped-call"
"""Benchmark: the data plane against the same work through canopen's PdoMap callbacks.

Both paths take the same stream of patch TPDO frames (``can.Message`` objects built once
from simulator resistances encoded by the patches' own ``PdoCodec``, in CAN arbitration
order, stamped inside each SYNC cycle's window), decode them with one shared ``analytic``
decoder and send the same force TPDOs to a sink bus, one after the other in one thread:

* data plane: :class:`canbus.master.dataplane.DataPlane` (``background=False``), frames given
  to ``on_message_received``, then ``publish_pending()`` once per cycle (every patch
  completed in the cycle decoded in one batch, as the publishing thread batches them
  when the bus is busy); force nodes are :class:`canbus.master.forcenode.ForceNode`.
* canopen: a ``RemoteNode`` per patch whose TPDO maps hold the patch's mapping; frames
  go through canopen's own ``MessageListener`` (``network.notify`` -> ``PdoMap.on_message``
  -> one callback per map reading ``var.raw``); per cycle the codes are turned into
  resistances and decoded in one batch (the same batching, so the comparison is the
  frame handling), then each force node, a canopen ``LocalNode`` with
  eds/skin-forces.eds, sets its TPDO variables (``var.raw = ...``) and ``transmit()``.

What the figures exclude: python-can's delivery of frames from the bus to a listener
(a virtual bus deep-copies each frame into a queue that the ``Notifier`` thread reads);
:func:`~skin.benchmarks.pipeline.notifier_rate` measures that part alone; the rigs are
:mod:`skin.benchmarks.dataplane_rigs`.
"""

from __future__ import annotations

import time
from typing import Any

from decoder.registry import create_decoder
from skin.benchmarks.dataplane_rigs import CanopenRig, DataPlaneRig, build_stream, contact_judge
from skin.benchmarks.pipeline import notifier_rate, pipeline_rate


def _timed(run: Any) -> tuple[float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    run()
    return time.perf_counter() - wall, time.process_time() - cpu


def run_dataplane_benchmark(patches: int = 16, cycles: int = 300, mode: str = "xyz", *,
                            repeats: int = 3, seed: int = 0,
                            contact: bool = True) -> dict[str, Any]:
    """Figures of both paths over the same stream; the best of ``repeats`` interleaved runs.

    Also python-can's delivery alone and the whole threaded path
    (:mod:`skin.benchmarks.pipeline`), each the best of its runs. ``contact``: the force
    nodes publish their patches' contact summaries (TPDO 8), as a host does by default.
    """
    stream = build_stream(patches, cycles, mode, seed)
    decoder = create_decoder("analytic")
    judge = contact_judge if contact else None
    fast = DataPlaneRig(stream, decoder, contact=judge)
    slow = CanopenRig(stream, decoder, contact=judge)
    try:
        fast.run(stream)
        slow.run(stream)
        identical = fast.sink.sent == slow.sink.sent
        frames_out = len(fast.sink.sent)
        times: dict[str, list[tuple[float, float]]] = {"dataplane": [], "per_patch": [],
                                                       "canopen": []}
        for _ in range(repeats):
            times["dataplane"].append(_timed(lambda: fast.run(stream)))
            times["per_patch"].append(_timed(lambda: fast.run(stream, per_patch=True)))
            times["canopen"].append(_timed(lambda: slow.run(stream)))
        stats = fast.plane.stats.snapshot()
    finally:
        fast.close()
        slow.close()
    n = stream.frame_count
    best = {k: min(v) for k, v in times.items()}
    result: dict[str, Any] = {
        "patches": patches, "cycles": cycles, "mode": mode, "repeats": repeats,
        "contact": contact,
        "frames_in": n, "frames_out": frames_out, "identical_output": identical,
        "all_samples_complete": stats["incomplete_samples"] == 0,
    }
    for key, (wall, cpu) in best.items():
        result[f"{key}_s"] = wall
        result[f"{key}_cpu_share"] = cpu / wall
        result[f"{key}_frames_in_per_s"] = n / wall
        result[f"{key}_frames_out_per_s"] = frames_out / wall
    result["speedup"] = best["canopen"][0] / best["dataplane"][0]
    result["speedup_per_patch"] = best["canopen"][0] / best["per_patch"][0]
    result["notifier_frames_per_s"] = max(notifier_rate() for _ in range(repeats))
    pipeline = max((pipeline_rate(stream, decoder, judge) for _ in range(min(repeats, 3))),
                   key=lambda figures: figures["frames_per_s"])
    result["pipeline_frames_per_s"] = pipeline["frames_per_s"]
    result["pipeline_receive_frames_per_cpu_s"] = pipeline["receive_frames_per_cpu_s"]
    own_cpu_s = best["dataplane"][1]  # the data plane's own path, on the same kind of clock
    result["pipeline_receive_vs_dataplane"] = pipeline["receive_frames_per_cpu_s"] * own_cpu_s / n
    result["pipeline_mean_batch"] = pipeline["mean_batch"]
    result["pipeline_all_complete"] = bool(pipeline["complete"])
    return result
