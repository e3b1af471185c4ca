"""An answer is a unit: the data of two patch answers never makes one sample.

A patch answers SYNC k with its TPDOs, in COB-ID order. On a slow or loaded machine an
answer can come late, run across the next SYNC, arrive whole one cycle late, or be
repeated or reordered on the way. Whatever happens, every complete sample is the
decode of one whole answer, an incomplete one carries an unbroken run of one answer, and
each patch gets exactly one sample per SYNC.
"""

# mypy: disable-error-code="no-untyped-call"
from __future__ import annotations

import can
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from decoder.reasons import Reason
from tests.support.rigs.dataplane import WINDOW_S, Host, Patch, load, sync_time

PERIOD_S = 0.01  # SYNC k at sync_time(k) = T0 + k / 100
PDOS = 7  # a 3-axis answer


def _answer(patch: Patch, cycle: int, scale: float, host: Host) -> tuple[list[can.Message],
                                                                          np.ndarray]:
    """The answer to SYNC ``cycle`` under ``load(scale)``, and what decoding it gives."""
    frames = patch.frames(load(scale), cycle)
    return frames, patch.expected(host.decoder).force_N[0]


def _at(frames: list[can.Message], start: float, gap_s: float = 1e-4) -> list[can.Message]:
    for k, msg in enumerate(frames):
        msg.timestamp = start + k * gap_s
    return frames


def _samples(host: Host, patch: int) -> list:
    return [f for f in host.out if f.patch == patch]


def _valid_with(patch: Patch, places: range) -> list[int]:
    """The taxels whose every value is carried by the frames at ``places`` of an answer."""
    missing = {t for place in range(PDOS) if place not in places for t in patch.carried(place)}
    return [t for t in range(9) if t not in missing]


def test_an_answer_running_past_the_next_sync_keeps_only_its_own_cycle(host: Host) -> None:
    """The issue's first trace: the tail of answer k arrives after SYNC k+1, before answer
    k+1: it must not complete cycle k+1."""
    a = host.patches[0]
    old, _ = _answer(a, 1, 1.0, host)
    new, want = _answer(a, 2, 0.4, host)
    host.sync(1)
    host.feed(_at(old[:4], sync_time(1) + 0.5 * WINDOW_S))
    host.sync(2)
    host.feed(_at(old[4:], sync_time(2) + 0.001) + _at(new, sync_time(2) + 0.002))
    host.sync(3)
    host.plane.flush()
    first, second, third = _samples(host, 1)
    assert (first.cycle, first.complete, second.cycle, second.complete) == (1, False, 2, True)
    np.testing.assert_allclose(second.force_N, want, rtol=1e-12)
    assert not third.complete and (third.reason == Reason.MISSING).all()
    assert host.plane.stats.late_frames == 3


def test_first_tpdo_before_the_sync_and_the_rest_after_it(host: Host) -> None:
    """The issue's second pattern: TPDO 1 of answer k before SYNC k+1, TPDO 2..7 after it,
    then answer k+1: the old code published TPDO 1 of k+1 with TPDO 2..7 of k."""
    a = host.patches[0]
    old, _ = _answer(a, 1, 1.0, host)
    new, want = _answer(a, 2, 0.4, host)
    host.sync(1)
    host.feed(_at(old[:1], sync_time(1) + 0.9 * WINDOW_S))
    host.sync(2)
    host.feed(_at(old[1:], sync_time(2) + 0.0001) + _at(new, sync_time(2) + 0.001))
    host.plane.flush()
    first, second = _samples(host, 1)
    assert not first.complete and list(np.flatnonzero(first.valid)) == _valid_with(a, range(1))
    assert second.complete and second.cycle == 2
    np.testing.assert_allclose(second.force_N, want, rtol=1e-12)


def test_a_whole_answer_one_cycle_late_is_one_stale_answer_never_a_mix(host: Host) -> None:
    """Classic CAN cannot tell an answer to SYNC k that arrives whole after SYNC k+1 from
    the answer to k+1 (docs/host.md): it is published for k+1, whole, and the real answer
    to k+1 that follows in the same window is turned away."""
    a = host.patches[0]
    old, want_old = _answer(a, 1, 1.0, host)
    new, _ = _answer(a, 2, 0.4, host)
    host.sync(1)
    host.sync(2)
    host.feed(_at(old, sync_time(2) + 0.0005) + _at(new, sync_time(2) + 0.002))
    host.plane.flush()
    first, second = _samples(host, 1)
    assert not first.complete and (first.reason == Reason.MISSING).all() and first.published
    assert second.complete and second.cycle == 2
    np.testing.assert_allclose(second.force_N, want_old, rtol=1e-12)
    assert host.plane.stats.duplicate_frames == PDOS and host.plane.stats.second_answers == 1


def test_two_frames_swapped_end_the_answer_at_the_swap(host: Host) -> None:
    a = host.patches[0]
    frames, _ = _answer(a, 1, 1.0, host)
    frames[3], frames[4] = frames[4], frames[3]
    host.sync(1)
    host.feed(_at(frames, sync_time(1) + 0.001))
    host.plane.flush()
    (sample,) = _samples(host, 1)
    assert not sample.complete
    assert list(np.flatnonzero(sample.valid)) == _valid_with(a, range(3))
    assert host.plane.stats.out_of_order_frames == 4  # place 4 first, then the rest


# -- the property ------------------------------------------------------------------------

CYCLES = 5

_plans = st.fixed_dictionaries({
    # when each answer starts, after its SYNC: up to two and a half periods late
    "delay": st.lists(st.floats(0.0, 2.5 * PERIOD_S), min_size=CYCLES, max_size=CYCLES),
    "gap": st.floats(2e-5, 8e-4),  # between frames of one answer
    "lost": st.sets(st.integers(0, CYCLES * PDOS - 1), max_size=8),
    "repeated": st.sets(st.integers(0, CYCLES * PDOS - 1), max_size=4),  # at once, same bytes
    "swapped": st.sets(st.integers(0, CYCLES * PDOS - 2), max_size=4),  # i and i+1 swap
})


def _stream(answers: list[list[can.Message]], plan: dict) -> list[tuple[can.Message, int]]:
    """One patch's frames as they arrive, each with the index of its answer.

    The patch sends its answers one after the other (a FIFO: an answer starts when the
    previous one is out), each ``delay`` after its SYNC; the way to the host then loses,
    repeats at once (a CAN retransmission) and swaps neighbouring frames. Runs of ``PDOS``
    or more consecutive losses are thinned: a case classic CAN cannot tell (docs/host.md),
    as is a late copy of an older frame, which a CAN bus never makes.
    """
    sent: list[tuple[can.Message, int]] = []
    t = 0.0
    for k, frames in enumerate(answers):
        t = max(t, sync_time(k + 1) + plan["delay"][k])
        for msg in frames:
            msg.timestamp = t
            t += plan["gap"]
            sent.append((msg, k))
    lost = set(plan["lost"])
    run = 0
    for i in range(len(sent)):
        run = run + 1 if i in lost else 0
        if run == PDOS:
            lost.discard(i)
            run = 0
    out: list[tuple[can.Message, int]] = []
    for i, item in enumerate(sent):
        if i not in lost:
            out.append(item)
            if i in plan["repeated"]:
                out.append(item)
    for i in sorted(plan["swapped"]):
        if i + 1 < len(out):
            out[i], out[i + 1] = out[i + 1], out[i]
    arrived = 0.0
    result = []
    for msg, k in out:  # a receiver stamps in arrival order
        arrived = max(arrived, msg.timestamp)
        copy = can.Message(timestamp=arrived, arbitration_id=msg.arbitration_id,
                           data=msg.data, is_extended_id=False)
        result.append((copy, k))
    return result


_RIG: list[Host] = []  # built once: hypothesis runs the test many times


@settings(max_examples=150, deadline=None)
@given(plan_a=_plans, plan_b=_plans, scales=st.permutations([0.2 * k for k in range(1, 11)]))
def test_no_sample_is_made_of_two_answers(plan_a: dict, plan_b: dict,
                                          scales: list[float]) -> None:
    if not _RIG:
        _RIG.append(Host())
    host = _RIG[0]
    host.reset()
    try:
        events: list[tuple[float, int, can.Message | None]] = []
        expected: dict[int, list[np.ndarray]] = {}
        for p, (patch, plan) in enumerate(zip(host.patches, (plan_a, plan_b), strict=True)):
            answers = []
            expected[patch.node.node_id] = []
            for k in range(CYCLES):
                frames, want = _answer(patch, k + 1, scales[p * CYCLES + k], host)
                answers.append(frames)
                expected[patch.node.node_id].append(want)
            events += [(msg.timestamp, 1, msg) for msg, _ in _stream(answers, plan)]
        events += [(sync_time(k), 0, None) for k in range(1, CYCLES + 1)]
        cycle = 0
        for _, _, msg in sorted(events, key=lambda e: (e[0], e[1])):
            if msg is None:
                cycle += 1
                host.sync(cycle)
            else:
                host.plane.on_message_received(msg)
        host.plane.flush()
        for node_id, wants in expected.items():
            samples = _samples(host, node_id)
            assert [s.cycle for s in samples] == list(range(1, CYCLES + 1))  # one per SYNC
            for sample in samples:
                ok = sample.valid
                assert any(np.allclose(sample.force_N[ok], want[ok], rtol=1e-12, atol=1e-12)
                           for want in wants), (node_id, sample.cycle, sample.complete)
                if sample.complete:
                    assert ok.all()
    finally:
        host.plane.stop()


def _run(host: Host, frames: list[can.Message], *, lag_s: list[float] | None,
         echo: bool = False) -> list[tuple]:
    """What the data plane publishes for ``frames`` (in bus order) and SYNCs 1..CYCLES.

    ``lag_s=None``: each SYNC opens its cycle where it lies in the bus's order (a listen-only
    host). Otherwise the host sends SYNC k at ``sync_time(k)`` (``on_sync_sent``) while its
    receive thread takes frame i ``lag_s[i]`` after it crossed the bus, in bus order;
    ``echo``: the bus hands it the echo of each SYNC, in its place (udp_multicast).
    """
    host.reset()
    try:
        if lag_s is None:
            events = [(msg.timestamp, 1, msg) for msg in frames]
        else:
            host.plane.sync_echo = echo
            if echo:
                syncs = [can.Message(timestamp=sync_time(k), arbitration_id=0x080,
                                     data=[k % 240 + 1], is_extended_id=False)
                         for k in range(1, CYCLES + 1)]
                frames = sorted(syncs + frames, key=lambda m: m.timestamp)  # stable
            events, taken = [], 0.0
            for i, msg in enumerate(frames):
                taken = max(taken, msg.timestamp + lag_s[i % len(lag_s)])
                events.append((taken, 1, msg))
        events += [(sync_time(k), 0, None) for k in range(1, CYCLES + 1)]
        cycle = 0
        for _, _, msg in sorted(events, key=lambda e: (e[0], e[1])):
            if msg is not None:
                host.plane.on_message_received(msg)
                continue
            cycle += 1
            sync = host.plane.on_sync if lag_s is None else host.plane.on_sync_sent
            sync(cycle, cycle % 240 + 1, sync_time(cycle))
        host.plane.flush()
        return [(f.patch, f.cycle, f.complete, f.force_N.tobytes(), f.valid.tobytes())
                for f in host.out]
    finally:
        host.plane.stop()


@settings(max_examples=100, deadline=None)
@given(plan_a=_plans, plan_b=_plans,
       lags=st.lists(st.floats(0.0, 2 * PERIOD_S), min_size=1, max_size=CYCLES * PDOS * 2),
       echo=st.booleans())
def test_a_receive_thread_behind_the_bus_loses_nothing(plan_a: dict, plan_b: dict,
                                                       lags: list[float], echo: bool) -> None:
    """The host sends SYNC k+1 while frames of cycle k are still queued for its receive thread
    (up to two periods behind): every sample is the one a host reading the bus in its own order
    publishes, bit for bit (docs/architecture.md: a cycle closes where the bus passed the next
    SYNC)."""
    if not _RIG:
        _RIG.append(Host())
    host = _RIG[0]
    frames = []
    for p, (patch, plan) in enumerate(zip(host.patches, (plan_a, plan_b), strict=True)):
        answers = [_answer(patch, k + 1, 0.3 + 0.1 * (p * CYCLES + k), host)[0]
                   for k in range(CYCLES)]
        frames += [msg for msg, _ in _stream(answers, plan)]
    frames.sort(key=lambda m: m.timestamp)
    assert _run(host, frames, lag_s=lags, echo=echo) == _run(host, frames, lag_s=None)


def test_a_silent_bus_opens_its_cycles_anyway(host: Host) -> None:
    """No frame shows a SYNC passed: each cycle still gets its sample, every taxel missing,
    once the bus has been silent for max_bus_lag_s after it."""
    plane, lag = host.plane, host.plane.max_bus_lag_s
    plane.on_sync_sent(1, 2, sync_time(1))
    plane.on_sync_sent(2, 3, sync_time(2))
    plane.on_sync_sent(3, 4, sync_time(2) + 0.5 * lag)
    assert not host.out  # cycle 1 stays open: the bus may still hold its frames
    plane.on_sync_sent(4, 5, sync_time(2) + lag + 1e-6)  # SYNC 2 unseen for max_bus_lag_s
    assert [(f.patch, f.cycle) for f in host.out] == [(1, 1), (2, 1)]
    assert all((f.reason == Reason.MISSING).all() for f in host.out)
    plane.flush()
    assert [f.cycle for f in host.out] == [1, 1, 2, 2, 3, 3, 4, 4]


def teardown_module() -> None:
    for host in _RIG:
        host.close()


def test_the_property_is_not_vacuous_on_a_clean_bus() -> None:
    """No faults, answers inside their windows: every sample complete and its own cycle's."""
    host = Host()
    try:
        wants = []
        for k in range(1, CYCLES + 1):
            host.sync(k)
            frames, want = _answer(host.patches[0], k, 0.3 * k, host)
            host.feed(_at(frames, sync_time(k) + 0.5 * WINDOW_S))
            wants.append(want)
        host.plane.flush()
        samples = _samples(host, 1)
        assert all(s.complete for s in samples)
        for sample, want in zip(samples, wants, strict=True):
            np.testing.assert_allclose(sample.force_N, want, rtol=1e-12)
    finally:
        host.close()


def test_a_cycle_is_answered_when_every_patch_that_can_answer_has(host: Host) -> None:
    """What the host waits for on stop: every online patch's whole answer, or one broken off."""
    a, b = host.patches
    assert host.plane.answered()  # no cycle open
    host.sync(1)
    assert not host.plane.answered()
    frames, _ = _answer(a, 1, 1.0, host)
    host.feed(_at(frames, sync_time(1) + 1e-4))
    assert not host.plane.answered()  # b has not answered
    other, _ = _answer(b, 1, 1.0, host)
    host.feed(_at([other[0], other[2]], sync_time(1) + 2e-3))  # one skipped: broken off
    assert host.plane.answered()
    host.sync(2)
    host.plane.set_online(2, False)  # a lost patch answers nothing
    host.feed(_at(_answer(a, 2, 1.0, host)[0], sync_time(2) + 1e-4))
    assert host.plane.answered()


def test_the_echo_of_a_sync_opens_its_cycle_a_lost_echo_the_next_one_does(host: Host) -> None:
    """udp_multicast hands the host the echo of its SYNCs: each opens its cycle where the
    bus passed it, matched by its counter; a lost echo is made good by the next one, and
    the echo of a SYNC already opened changes nothing."""
    plane, a = host.plane, host.patches[0]
    plane.sync_echo = True

    def echo(cycle: int) -> can.Message:
        return can.Message(timestamp=sync_time(cycle), arbitration_id=0x080,
                           data=[cycle % 240 + 1], is_extended_id=False)

    for k in (1, 2, 3):
        plane.on_sync_sent(k, k % 240 + 1, sync_time(k))
    host.feed([echo(1)])
    host.feed(_at(_answer(a, 1, 0.5, host)[0], sync_time(1) + 1e-3))
    host.feed(_at(_answer(a, 2, 0.6, host)[0][:1], sync_time(1) + 2e-3))  # stamped in 1
    host.feed([echo(3)])  # SYNC 2's echo was lost: this one opens 2, then 3
    host.feed([echo(2)])  # late: nothing
    host.feed(_at(_answer(a, 3, 0.7, host)[0], sync_time(3) + 1e-3))
    plane.flush()
    assert [(f.cycle, f.complete) for f in _samples(host, 1)] == [(1, True), (2, False),
                                                                 (3, True)]
