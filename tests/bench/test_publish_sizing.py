"""The CPU a shape needs, from runs of ``skin bench publish`` (``skin.benchmarks.publish_sizing``):
the costs fitted from runs give back the runs' needs, and any shape's need and cores."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from skin.benchmarks.publish_fit import MACHINE_LIMIT, PROCESS_LIMIT_PCT
from skin.benchmarks.publish_sizing import (
    Cost,
    Costs,
    bus_frames_per_cycle,
    costs_from_runs,
    shape_needs,
)

RATE = 100.0
costs = st.builds(Costs, *(st.builds(Cost, st.floats(0.0, 3_000.0), st.floats(0.5, 60.0))
                           for _ in range(3)))


def _run(truth: Costs, patches: int, hosts: int) -> dict[str, Any]:
    """What a run of that shape reports when every role costs what ``truth`` says."""
    frames = bus_frames_per_cycle(patches, hosts, RATE)
    return {"patches": patches, "hosts": hosts, "rate_hz": RATE, "cpu": {
        "host_frames_per_cycle": frames,
        "need_pct": {"hosts": [(truth.host.fixed_us + truth.host.per_unit_us * f) * RATE / 1e4
                               for f in frames],
                     "simulator": sum(truth.simulator.fixed_us + truth.simulator.per_unit_us * f
                                      for f in frames) * RATE / 1e4,
                     "reader": (truth.reader.fixed_us
                                + truth.reader.per_unit_us * patches * RATE) / 1e4}}}


def test_a_bus_s_frames_per_cycle_are_the_patches_and_force_pdos_sync_and_heartbeats() -> None:
    # 2 patches a bus: 7 resistance + 8 force PDOs each, a SYNC, and 4 heartbeats a second
    # (the patches' and their force nodes'): 3,104 frames/s, as the bench's hosts counted
    assert bus_frames_per_cycle(8, 4, RATE) == pytest.approx([31.04] * 4)
    assert bus_frames_per_cycle(32, 4, RATE) == pytest.approx([121.16] * 4)


@given(costs, st.sampled_from([(8, 4), (16, 4), (24, 4), (32, 4), (12, 2), (5, 5)]),
       st.sampled_from([(32, 4), (48, 4), (64, 8), (20, 1)]))
def test_costs_fitted_from_two_shapes_give_back_what_each_shape_needs(
        truth: Costs, small: tuple[int, int], large: tuple[int, int]) -> None:
    runs = [_run(truth, *small), _run(truth, *large)]
    if small[0] / small[1] == large[0] / large[1]:
        with pytest.raises(ValueError, match="runs with two or more different"):
            costs_from_runs(runs)
        return
    fitted = costs_from_runs(runs)
    for shape, run in zip((small, large), runs, strict=True):
        need = shape_needs(fitted, *shape, RATE)
        want = run["cpu"]["need_pct"]
        assert need.hosts_pct == pytest.approx(want["hosts"], rel=1e-6, abs=1e-6)
        assert need.simulator_pct == pytest.approx(want["simulator"], rel=1e-6, abs=1e-6)
        assert need.reader_pct == pytest.approx(want["reader"], rel=1e-6, abs=1e-6)


def test_a_shape_gets_the_fewest_cores_that_carry_it_and_none_if_a_process_cannot() -> None:
    per_frame = Costs(Cost(1_000.0, 10.0), Cost(250.0, 5.0), Cost(50_000.0, 20.0))
    need = shape_needs(per_frame, 32, 4, RATE)
    # a host: (1,000 + 10 x 121.16) us a cycle at 100 Hz = 22.1 %; the simulator 4 x
    # (250 + 5 x 121.16) us = 34.2 %; the reader 5 % + 3,200 x 20 us = 11.4 %
    assert need.hosts_pct == pytest.approx([22.116] * 4)
    assert need.simulator_pct == pytest.approx(34.232)
    assert need.reader_pct == pytest.approx(11.4)
    assert need.total_pct == pytest.approx(134.096)
    for shape in (need, shape_needs(per_frame, 64, 4, RATE), shape_needs(per_frame, 8, 8, RATE)):
        assert shape.cores is not None
        usable = MACHINE_LIMIT * 100.0
        assert usable * (shape.cores - 1) <= shape.total_pct < usable * shape.cores
    robot = shape_needs(per_frame, 32, 4, RATE, simulated=False)
    assert robot.simulator_pct == 0.0 and robot.hosts_pct == need.hosts_pct
    assert robot.total_pct == pytest.approx(need.total_pct - need.simulator_pct)
    assert robot.cores == 2  # 100 % < 60 % of 200 %
    crowded = shape_needs(per_frame, 127, 1, RATE)
    assert max(crowded.hosts_pct) >= PROCESS_LIMIT_PCT and crowded.cores is None
