"""A patch's state is derived in one place from the facts, whatever order the events of
its threads are handled in (canbus.master.patchstate)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import canopen
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canbus.master.hostconfig import PatchConfig
from canbus.master.liveness import HeartbeatMonitor
from canbus.master.patch_setup import configured_info, plan_setup
from canbus.master.patchstate import PatchStates, Transition, derive
from canbus.od import load_od

NODE = 3
PERIOD_MS = 100
OPERATIONAL, PRE_OPERATIONAL, STOPPED, BOOTUP = 0x05, 0x7F, 0x04, 0x00


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@dataclass
class Bench:
    """A heartbeat consumer and the states, with every callback of the consumer held back
    (``pending``) until the test hands it on: any interleaving of the notifier thread
    (heartbeats), the consumer's thread (lost) and the set-up workers can be played."""

    listen_only: bool
    clock: Clock = field(default_factory=Clock)
    pending: list[tuple[str, int]] = field(default_factory=list)
    applied: list[Transition] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.monitor = HeartbeatMonitor(
            canopen.Network(), PERIOD_MS, clock=self.clock,
            on_boot=lambda n: self.pending.append(("boot", -1)),
            on_lost=lambda n: self.pending.append(("lost", -1)),
            on_return=lambda n, s: self.pending.append(("return", s)),
            on_change=lambda n, s: self.pending.append(("change", s)))
        self.monitor.watch(NODE, judged=True)
        self.states = PatchStates({NODE: self.monitor}, listen_only=self.listen_only,
                                  apply=lambda t, f: self.applied.append(t))
        self.setup = plan_setup(NODE, load_od("skin-patch", NODE), "xyz",
                                configured_info(PatchConfig(NODE)))
        if self.listen_only:
            self.states.planned(NODE, self.setup)
        self.jobs: list[int] = []  # incarnations whose set-up is running

    def beat(self, state: int) -> None:
        self.monitor.on_heartbeat(0x700 + NODE, bytearray([state]), 0.0)

    def handle(self, event: tuple[str, int]) -> None:
        """What the policies do with a consumer's callback (active.py, follower.py)."""
        kind, state = event
        states = self.states
        if kind == "boot":
            states.booted(NODE)
        elif kind == "return":
            states.returned(NODE, state)
        elif kind == "change":
            if self.listen_only:
                states.saw_nmt(NODE, state)
        else:
            states.recheck(NODE)
        if not self.listen_only and (incarnation := states.needs_setup(NODE)) is not None:
            self.jobs.append(incarnation)

    def finish_job(self, ok: bool) -> None:
        if not self.jobs:
            return
        incarnation = self.jobs.pop(0)
        if ok:
            self.monitor.expect(NODE)
            self.states.set_up(NODE, incarnation, self.setup)
        else:
            self.states.setup_failed(NODE, incarnation, "set-up failed: garbled",
                                     permanent=False)


def _expected(bench: Bench) -> str:
    """The state the facts call for once every event has been handled."""
    return derive(bench.states.facts(NODE), listen_only=bench.listen_only)[0]


EVENTS = st.lists(st.one_of(
    st.tuples(st.just("beat"), st.sampled_from([OPERATIONAL, PRE_OPERATIONAL, STOPPED,
                                                BOOTUP])),
    st.tuples(st.just("silence"), st.floats(0.0, 0.5)),  # the clock moves on, then a check
    st.tuples(st.just("handle"), st.integers(0, 5)),  # hand on the n-th held-back callback
    st.tuples(st.just("job"), st.booleans()),  # a set-up worker finishes
), max_size=60)


@settings(max_examples=200)
@given(events=EVENTS, listen_only=st.booleans())
def test_no_interleaving_leaves_a_patch_in_a_stale_state(
        events: list[tuple[str, object]], listen_only: bool) -> None:
    bench = Bench(listen_only)
    for kind, arg in events:
        if kind == "beat":
            assert isinstance(arg, int)
            bench.beat(arg)
        elif kind == "silence":
            assert isinstance(arg, float)
            bench.clock.now += arg
            bench.monitor.check()
        elif kind == "handle" and bench.pending:
            assert isinstance(arg, int)
            bench.handle(bench.pending.pop(arg % len(bench.pending)))
        elif kind == "job" and not listen_only:
            assert isinstance(arg, bool)
            bench.finish_job(arg)
    while bench.pending:  # the late ones, in any order: here the oldest last
        bench.handle(bench.pending.pop())
    state = bench.states.state(NODE)
    assert state == _expected(bench)
    # Every change was handed to the host once, in order, and ends where the state is.
    if bench.applied:
        assert bench.applied[-1].new == state
        assert all(a.new == b.old for a, b in zip(bench.applied, bench.applied[1:],
                                                   strict=False))
    # The rule a user relies on: a patch heard beating OPERATIONAL after every overdue
    # check, whose set-up of this incarnation succeeded, is operational, never lost.
    if not bench.monitor.lost(NODE) and bench.states.view(NODE).state == "lost":
        pytest.fail("lost while its heartbeat is not overdue")


def test_a_late_on_lost_cannot_win_over_a_heartbeat_handled_before_it() -> None:
    """The stall of issue 20: the consumer marks the patch lost, a heartbeat is handled
    (its return), then the consumer's on_lost runs: the patch is operational."""
    bench = Bench(listen_only=False)
    bench.beat(OPERATIONAL)
    bench.handle(bench.pending.pop())  # first heard: configure it
    bench.finish_job(True)
    assert bench.states.state(NODE) == "operational"
    bench.clock.now += 0.2  # a SIGSTOP of 200 ms
    assert bench.monitor.check() == [NODE]
    bench.beat(OPERATIONAL)  # the queued heartbeat, handled before the late on_lost
    lost, back = bench.pending
    bench.handle(back)
    bench.handle(lost)
    assert bench.states.state(NODE) == "operational"
    assert [t.new for t in bench.applied][-2:] != ["operational", "lost"]


def test_each_change_is_logged_once_and_history_is_bounded(
        caplog: pytest.LogCaptureFixture) -> None:
    bench = Bench(listen_only=True)
    caplog.set_level(logging.INFO, logger="canbus.master.patchstate")
    for _ in range(40):  # operational, stopped, operational, ... heard as NMT changes
        bench.states.saw_nmt(NODE, OPERATIONAL, heard=True)
        bench.states.saw_nmt(NODE, STOPPED)
    lines = [r.getMessage() for r in caplog.records]
    assert lines[:3] == ["patch 3: operational", "patch 3: stopped", "patch 3: operational"]
    assert len(lines) == 80 == bench.states.view(NODE).changes
    assert len(bench.states.view(NODE).history) == 16  # the newest kept
    assert all(hasattr(r, "patch_state") for r in caplog.records)


def test_a_setup_failure_keeps_the_reason_and_only_a_refusal_fails() -> None:
    bench = Bench(listen_only=False)
    bench.beat(PRE_OPERATIONAL)
    bench.handle(bench.pending.pop())
    incarnation = bench.jobs[0]
    assert bench.states.setup_failed(NODE, incarnation, "set-up failed: no answer",
                                     permanent=False) == 1
    view = bench.states.view(NODE)
    assert (view.state, view.reason, view.setup_failures) == \
        ("configuring", "set-up failed: no answer", 1)
    assert bench.states.needs_setup(NODE) == incarnation  # still to be configured: retried
    bench.states.setup_failed(NODE, incarnation, "set-up failed: not a patch", permanent=True)
    assert bench.states.view(NODE).state == "failed"
    assert bench.states.needs_setup(NODE) is None
    # A failure of an older incarnation (the node booted since) is void.
    bench.beat(BOOTUP)
    bench.handle(bench.pending.pop())
    assert bench.states.setup_failed(NODE, incarnation, "late", permanent=True) is None
    assert bench.states.view(NODE).state == "configuring"
