"""``skin plan``'s arithmetic (one node's share times the nodes, canbus.nodeload) gives the
answer the frame-by-frame count gives (``--exact``, the first planner): the same buses
needed, the same loads and rates to rounding, the same printed answer."""

from __future__ import annotations

import itertools
import math

import pytest

from canbus import busload
from canbus.busload import plan
from canbus.sizing import size
from skin.cli import main

SIZES = (1, 2, 3, 5, 8, 16, 24, 33)
RATES = (10.0, 100.0, 250.0, 1000.0)
MODES = ("z", "xyz")
DATA_BITRATES = (None, 5_000_000)
FORCES: tuple[busload.Forces, ...] = ("same-bus", "other-bus", "none")
TARGETS = (30.0, 70.0, 95.0)


def _close(a: float | None, b: float | None) -> bool:
    if a is None or b is None:
        return a is b
    return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-9)


@pytest.mark.parametrize(("mode", "data_bitrate", "forces"),
                         itertools.product(MODES, DATA_BITRATES, FORCES))
def test_the_buses_needed_are_the_frame_by_frame_answer(
        mode: str, data_bitrate: int | None, forces: busload.Forces) -> None:
    for patches, rate, target in itertools.product(SIZES, RATES, TARGETS):
        kwargs = dict(data_bitrate=data_bitrate, target_pct=target, forces=forces)
        fast = size(patches, rate, mode, 1_000_000, **kwargs)  # type: ignore[arg-type]
        exact = size(patches, rate, mode, 1_000_000, exact=True, **kwargs)  # type: ignore[arg-type]
        where = (patches, rate, target)
        assert (fast.buses, fast.force_buses, fast.patches_per_bus) == \
            (exact.buses, exact.force_buses, exact.patches_per_bus), where
        assert _close(fast.load_worst_pct, exact.load_worst_pct), where
        assert _close(fast.max_rate_hz, exact.max_rate_hz), where


@pytest.mark.parametrize(("mode", "data_bitrate", "forces"),
                         itertools.product(MODES, DATA_BITRATES, FORCES))
def test_every_bus_has_the_frame_by_frame_figures(
        mode: str, data_bitrate: int | None, forces: busload.Forces) -> None:
    for patches, rate, heartbeat_ms in itertools.product(SIZES, RATES, (0, 100)):
        for buses in sorted({1, 2, 3, patches} & set(range(1, patches + 1))):
            kwargs = dict(data_bitrate=data_bitrate, forces=forces, buses=buses,
                          heartbeat_ms=heartbeat_ms)
            fast = plan(patches, rate, mode, 1_000_000, **kwargs)  # type: ignore[arg-type]
            exact = plan(patches, rate, mode, 1_000_000, exact=True,
                         **kwargs)  # type: ignore[arg-type]
            for a, b in zip(fast.buses, exact.buses, strict=True):
                assert (a.name, a.patches, a.force_nodes, a.fits, a.over_target) == \
                    (b.name, b.patches, b.force_nodes, b.fits, b.over_target)
                assert list(a.frames_per_s) == list(b.frames_per_s)  # printed in this order
                assert all(_close(a.frames_per_s[k], b.frames_per_s[k])
                           for k in a.frames_per_s)
                for field in ("load_best_pct", "load_worst_pct", "cycle_ms_best",
                              "cycle_ms_worst", "max_rate_hz", "max_patch_samples_per_s",
                              "latency_ms_worst"):
                    assert _close(getattr(a, field), getattr(b, field)), (field, patches, buses)
            assert fast.worst_bus == exact.worst_bus and _close(fast.frames_per_s,
                                                                exact.frames_per_s)


@pytest.mark.parametrize("args", [
    ["--patches", "8", "--rate", "100"],
    ["--patches", "33", "--rate", "250", "--mode", "z", "--fd", "--buses", "3"],
    ["--patches", "24", "--rate", "100", "--forces", "other-bus", "--buses", "2"],
    # Not 15 or 16: their worst cycle is a tie to two decimals (28.115, 29.985 ms exactly),
    # which the two sums' last-bit rounding prints either way; the figures agree to 1e-9.
    ["--patches", "12", "--rate", "500", "--no-contact", "--target", "30"],
    ["--patches", "33", "--rate", "10", "--max-load", "50"],
])
def test_the_printed_answer_is_the_frame_by_frame_one(
        args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["plan", *args]) == 0
    fast = capsys.readouterr()
    assert main(["plan", *args, "--exact"]) == 0
    assert capsys.readouterr() == fast


def test_the_latency_is_the_longest_frame_and_the_cycle() -> None:
    # one 3-axis patch alone, no forces: a 8-byte PDO (135 bits) may be on the wire when
    # the SYNC is due, then SYNC (65), 6 x 135 and one 6-byte PDO (47 + 48 + 20 = 115)
    (bus,) = plan(1, 100, "xyz", 1_000_000, forces="none").buses
    assert bus.latency_ms_worst == pytest.approx((135 + 65 + 6 * 135 + 115) / 1000)
    (over,) = plan(8, 100, "xyz", 1_000_000).buses  # does not fit: queues grow
    assert over.latency_ms_worst is None
