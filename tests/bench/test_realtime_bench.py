"""``skin bench realtime``: its figures come from what the processes measured, and a short
run on loopback gives every one of them."""

from __future__ import annotations

import pytest

from skin.benchmarks.realtime import _figures, run_realtime_benchmark


def _mark(t: float, frames: int, bare_cpu: float, host_cpu: float, sim_cpu: float,
          delays: list[float] | None = None) -> dict:
    listener: dict = {"time": t, "frames": frames, "cpu_s": bare_cpu}
    if delays is not None:
        listener["sync_to_last_force_pdo_ms"] = delays
        listener["last_patch_pdo_to_last_force_pdo_ms"] = [d / 2 for d in delays]
    return {"time": t, "listener": listener, "host_cpu_s": host_cpu, "sim_cpu_s": sim_cpu}


def test_the_figures_are_per_frame_of_the_window_and_the_host_is_set_against_the_bare_receiver(
        ) -> None:
    host = {"steady_complete_pct": 99.95,
            "stats": {"steady_samples": 2000, "samples": 2100, "batches": 300, "late_frames": 3,
                      "sync_overruns": 0}}
    start = _mark(100.0, 1_000, 1.0, 5.0, 2.0)
    end = _mark(110.0, 101_000, 2.0, 8.0, 3.0, delays=[1.0, 2.0, 3.0, 4.0])
    r = _figures(host, start, end, [0.0, 0.1, 0.5], realtime=True, host_realtime=True,
                 sim_realtime=False)
    assert r["frames_per_s"] == pytest.approx(10_000)
    assert r["host_cpu_us_per_frame"] == pytest.approx(30.0)  # 3 s of CPU over 100,000 frames
    assert r["bare_pycan_recv_cpu_us_per_frame"] == pytest.approx(10.0)
    assert r["host_over_bare"] == pytest.approx(3.0)
    assert r["host_cpu_pct"] == pytest.approx(30.0) and r["sim_cpu_pct"] == pytest.approx(10.0)
    assert r["complete_pct"] == 99.95 and r["incomplete_pct_per_window"]["max"] == 0.5
    assert r["mean_batch"] == 7.0
    assert r["sync_to_last_force_pdo_ms"]["p50"] == pytest.approx(2.5)
    assert r["last_patch_pdo_to_last_force_pdo_ms"]["max"] == pytest.approx(2.0)


def test_a_short_run_on_loopback_gives_every_figure() -> None:
    result = run_realtime_benchmark(patches=2, hogs=1, seconds=2.0, variants=(True,),
                                    log=lambda *_: None)
    (run,) = result["runs"]
    assert run["realtime"] and run["steady_samples"] > 0
    assert run["complete_pct"] is not None and 0 < run["complete_pct"] <= 100
    assert run["frames_per_s"] > 0 and run["host_cpu_us_per_frame"] > 0
    assert run["bare_pycan_recv_cpu_us_per_frame"] > 0
    assert run["sync_to_last_force_pdo_ms"]["p50"] is not None
    assert run["last_patch_pdo_to_last_force_pdo_ms"]["p50"] is not None
