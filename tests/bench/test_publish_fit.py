"""``skin bench publish`` says where its CPU went and whether the machine carried the shape
(``skin.benchmarks.publish_fit``, ``skin.benchmarks.proccpu``), and when it did not, its text
does not present the complete share as Zenoh's loss."""

from __future__ import annotations

import math
import os
from dataclasses import replace

import pytest
from hypothesis import given
from hypothesis import strategies as st

from skin.benchmarks.proccpu import MachineTicks, busy_pct, machine_ticks, process_cpu_s
from skin.benchmarks.publish_fit import (
    MACHINE_LIMIT,
    OTHER_LIMIT,
    PROCESS_LIMIT_PCT,
    Role,
    cpu_figures,
    verdict,
)
from skin.commands.bench.publish import print_publish
from skin.errors import BusError

pct = st.floats(0.0, 400.0, allow_nan=False)
roles = st.lists(st.builds(Role, name=st.sampled_from(["host0", "host1", "simulator", "reader"]),
                           cpu_pct=pct, need_pct=st.none() | pct), min_size=1, max_size=8)
cores = st.integers(1, 64)


def _light(count: int, capacity_pct: float) -> list[Role]:
    """Processes that together use a third of what the machine may give them."""
    each = min(PROCESS_LIMIT_PCT / 2, MACHINE_LIMIT * capacity_pct / 3 / count)
    return [Role(f"host{k}", each, each) for k in range(count)]


@given(roles, cores, st.floats(0.0, 1.0))
def test_a_process_at_the_limit_of_a_core_does_not_fit_and_is_named(
        shape: list[Role], n: int, busy: float) -> None:
    capacity = 100.0 * n
    saturated = Role("simulator-x", 10.0, PROCESS_LIMIT_PCT)
    judged = verdict([*shape, saturated], capacity, busy * capacity)
    assert not judged.fits
    assert f"simulator-x needs {PROCESS_LIMIT_PCT:.0f} % of a core" in judged.why


@given(st.integers(1, 8), cores, st.floats(1.0, 3.0))
def test_processes_that_need_more_than_the_machine_gives_do_not_fit(
        count: int, n: int, over: float) -> None:
    capacity = 100.0 * n
    each = min(MACHINE_LIMIT * capacity * over / count, PROCESS_LIMIT_PCT - 1)
    shape = [Role(f"host{k}", each / 2, each) for k in range(count)]
    if sum(r.need_pct or 0 for r in shape) < MACHINE_LIMIT * capacity:
        shape += [Role(f"more{k}", 1.0, each)
                  for k in range(int(MACHINE_LIMIT * capacity / each) + 1)]
    judged = verdict(shape, capacity, 0.0)
    assert not judged.fits
    assert "of a core in all, the machine has" in judged.why


@given(st.integers(1, 8), cores)
def test_a_shape_with_room_on_an_idle_machine_fits_and_says_what_it_needs(
        count: int, n: int) -> None:
    capacity = 100.0 * n
    shape = _light(count, capacity)
    judged = verdict(shape, capacity, sum(r.cpu_pct for r in shape))
    assert judged.fits, judged.why
    assert judged.why.startswith(f"the processes need {sum(r.cpu_pct for r in shape):.0f} % ")


@given(st.integers(1, 8), cores, st.floats(0.01, 1.0))
def test_other_work_filling_the_machine_is_said_and_the_bench_alone_is_not_blamed_on_it(
        count: int, n: int, more: float) -> None:
    capacity = 100.0 * n
    shape = _light(count, capacity)
    own = sum(r.cpu_pct for r in shape)
    other = max(OTHER_LIMIT * capacity, MACHINE_LIMIT * capacity - own) + more * capacity
    crowded = verdict(shape, capacity, own + other)
    assert not crowded.fits
    assert f"the machine was shared: other work took {other:.0f} % of a core" in crowded.why
    roomy = verdict(shape, capacity, own + OTHER_LIMIT * capacity)  # others used, room left
    assert roomy.fits, roomy.why
    count = math.ceil(0.95 * capacity / (PROCESS_LIMIT_PCT - 5))
    heavy = [Role(f"host{k}", 0.95 * capacity / count, 0.95 * capacity / count)
             for k in range(count)]
    alone = verdict(heavy, capacity, capacity)  # the bench's own processes filled it
    assert "of a core in all" in alone.why and "shared" not in alone.why


@given(roles, cores, st.floats(0.0, 1.0), st.data())
def test_more_need_or_more_other_work_never_makes_a_shape_fit(
        shape: list[Role], n: int, busy: float, data: st.DataObject) -> None:
    capacity = 100.0 * n
    before = verdict(shape, capacity, busy * capacity)
    k = data.draw(st.integers(0, len(shape) - 1))
    more = data.draw(st.floats(0.0, 400.0))
    worse = [*shape]
    worse[k] = replace(shape[k], need_pct=(shape[k].need_pct or 0.0) + more) \
        if shape[k].need_pct is not None else shape[k]
    assert verdict(worse, capacity, busy * capacity).fits <= before.fits
    assert verdict(shape, capacity, min(capacity, busy * capacity + more)).fits <= before.fits


def test_a_process_that_did_no_work_does_not_fit() -> None:
    judged = verdict([Role("host0", 1.0, 1.0), Role("host1", 0.0, None)], 200.0, 1.0)
    assert not judged.fits and "host1 did no work in the window" in judged.why


@pytest.mark.parametrize(("shape", "capacity"), [([], 200.0), ([Role("a", 1.0, 1.0)], 0.0)])
def test_a_verdict_without_processes_or_cores_is_refused(shape: list[Role],
                                                         capacity: float) -> None:
    with pytest.raises(ValueError, match="at least one process and a positive capacity"):
        verdict(shape, capacity, 0.0)


def _host(cpu_s: float, seconds: float, frames: int, cycles: int) -> dict:
    return {"cpu_s": cpu_s, "seconds": seconds, "frames_received": frames // 2,
            "frames_sent": frames - frames // 2, "first_cycle": 11, "last_cycle": 10 + cycles}


def test_the_need_is_the_cost_per_frame_times_the_frames_the_full_rate_makes() -> None:
    # host0 kept the rate (1,000 cycles in 10 s); host1 ran half of them: it needs twice
    # what it used. The simulator's 2 s of CPU over the 2 buses' 180,000 frames are
    # 11.1 us a frame; the reader's 0.5 s over 8,000 samples 62.5 us a sample.
    cpu, judged = cpu_figures(
        [_host(1.2, 10.0, 120_000, 1_000), _host(0.6, 10.0, 60_000, 500)],
        {"cpu_s": 0.5, "seconds": 10.0}, 8_000, 2.0, 10.0, 60.0, 2, 8, 100.0)
    assert cpu["hosts_pct"] == pytest.approx([12.0, 6.0])
    assert cpu["host_us_per_frame"] == pytest.approx([10.0, 10.0])
    assert cpu["host_frames_per_s"] == pytest.approx([12_000.0, 6_000.0])
    assert cpu["host_frames_per_cycle"] == pytest.approx([120.0, 120.0])
    assert cpu["need_pct"]["hosts"] == pytest.approx([12.0, 12.0])
    assert cpu["simulator_us_per_frame"] == pytest.approx(2e6 / 180_000)
    assert cpu["need_pct"]["simulator"] == pytest.approx(2e6 / 180_000 * 24_000 / 1e4)
    assert cpu["reader_us_per_sample"] == pytest.approx(62.5)
    assert cpu["need_pct"]["reader"] == pytest.approx(62.5 * 800 / 1e4)
    assert cpu["total_pct"] == pytest.approx(12 + 6 + 20 + 5)
    assert cpu["other_pct"] == pytest.approx(60 - 43)
    assert cpu["capacity_pct"] == 200.0
    assert judged.fits, judged.why


@given(st.floats(0.01, 5.0), st.integers(1, 20_000), st.integers(1, 3_000))
def test_a_host_that_kept_the_rate_needs_what_it_used(cpu_s: float, frames_per_cycle: int,
                                                      cycles: int) -> None:
    seconds = cycles / 100.0
    cpu, _ = cpu_figures([_host(cpu_s, seconds, frames_per_cycle * cycles, cycles)],
                         {"cpu_s": 0.1, "seconds": seconds}, cycles, 0.1, seconds, 0.0, 1, 1,
                         100.0)
    assert cpu["need_pct"]["hosts"][0] == pytest.approx(cpu["hosts_pct"][0])


def test_a_host_without_a_cycle_or_a_frame_has_no_need_and_does_not_fit() -> None:
    cpu, judged = cpu_figures([_host(0.2, 10.0, 0, 0)], {"cpu_s": 0.1, "seconds": 10.0}, 0,
                              0.1, 10.0, 10.0, 2, 1, 100.0)
    assert cpu["need_pct"]["hosts"] == [None] and cpu["host_us_per_frame"] == [None]
    assert cpu["need_pct"]["reader"] is None
    assert not judged.fits and "host0 did no work" in judged.why


STAT = """cpu  100 20 30 800 50 5 5 0 7 0
cpu0 50 10 15 400 25 3 2 0 7 0
cpu1 50 10 15 400 25 2 3 0 0 0
intr 12345
"""


def test_the_machine_s_busy_time_is_everything_but_idle_and_iowait() -> None:
    start = machine_ticks(STAT)
    assert start == MachineTicks(busy=160, total=1010, cpus=2)
    end = MachineTicks(busy=start.busy + 150, total=start.total + 200, cpus=2)
    assert busy_pct(start, end) == pytest.approx(150.0)  # 2 CPUs, 3/4 busy
    assert busy_pct(start, start) == 0.0
    with pytest.raises(ValueError, match="not the 'cpu' total"):
        machine_ticks("intr 1\n")


def test_a_process_s_cpu_time_is_read_and_a_gone_process_is_named() -> None:
    assert process_cpu_s(os.getpid()) > 0  # any machine: a process's own CPU time
    with pytest.raises(BusError, match="no CPU time for process 0"):
        process_cpu_s(0)


def _result(fits: bool) -> dict:
    cpu, judged = cpu_figures([_host(1.2, 10.0, 120_000, 1_000)], {"cpu_s": 0.5,
                              "seconds": 10.0}, 8_000, 2.0, 10.0, 60.0, 2, 8, 100.0)
    nan = {"p50": 1.0, "p99": 2.0, "max": 3.0}
    return {"hosts": 1, "patches": 8, "cycles": 1_000, "seconds": 10.0, "express": False,
            "reader_complete_pct": 40.0, "samples_expected": 8_000, "host_complete_pct": 41.0,
            "latency_ms": nan, "pdo_latency_ms": nan, "zenoh_added_p99_ms": 0.1,
            "publish_cpu_us_per_sample_parts": {"thread": 1.0},
            "host_cpu_us_per_sample": 50.0, "publish_cpu_us_per_sample": 1.0,
            "publish_share_pct": 2.0, "reader_cpu_pct": 5.0, "reader_cpu_us_per_sample": 62.5,
            "codec": {}, "load_average": {"before": [1.0], "after": [1.0]}, "cpu_count": 2,
            "rate_hz": 100.0, "cpu": cpu, "fits_machine": fits,
            "why": judged.why if fits else "host0 needs 140 % of a core"}


def test_the_text_says_when_the_machine_did_not_carry_the_shape(
        capsys: pytest.CaptureFixture[str]) -> None:
    print_publish(_result(fits=False))
    out = capsys.readouterr().out
    assert "does not fit this machine: host0 needs 140 % of a core\n" in out
    assert ("reader got 40.000 % of 8,000 samples complete (the hosts made 41.000 % "
            "complete): what this machine carried, not what Zenoh lost\n") in out
    assert "CPU, % of a core: hosts 12, simulator 20, reader 5: 37 of the machine's 200" in out
    print_publish(_result(fits=True))
    out = capsys.readouterr().out
    assert "fits this machine: the processes need" in out
    assert "not what Zenoh lost" not in out
