"""``--cpu``: which CPUs a command's threads run on."""

from __future__ import annotations

import os
import threading

import pytest

from skin.commands.common.cpu import parse_cpus, pinned
from skin.errors import ConfigError

needs_affinity = pytest.mark.skipif(not hasattr(os, "sched_setaffinity"),
                                    reason="this platform has no sched_setaffinity")


@pytest.mark.parametrize(("spec", "expected"), [
    ("all", None), ("ALL", None), ("last", {7}), ("3", {3}), ("0,2-3", {0, 2, 3}),
    ("4-4", {4}), (" 1 , 5 ", {1, 5}),
])
def test_specs(spec: str, expected: set[int] | None) -> None:
    assert parse_cpus(spec, set(range(8))) == expected


@pytest.mark.parametrize(("spec", "message"), [
    ("x", "expected a list like 3 or 0,2-3"), ("1,", "expected a list"),
    ("3-1", "'3-1' is not a CPU range"), ("-1", "expected a list"),
    ("2,9", r"CPU\(s\) 9 not available to this process \(it may use 0-3,6\)"),
])
def test_bad_specs_name_the_flag_and_the_problem(spec: str, message: str) -> None:
    with pytest.raises(ConfigError, match=rf"^--cpu: .*{message}"):
        parse_cpus(spec, {0, 1, 2, 3, 6})


@needs_affinity
def test_pinned_holds_for_the_threads_started_inside_and_is_undone() -> None:
    seen: dict[str, set[int]] = {}

    def body() -> None:
        before = os.sched_getaffinity(0)
        with pinned("last") as cpus:
            assert cpus == {max(before)}
            worker = threading.Thread(target=lambda: seen.update(child=os.sched_getaffinity(0)))
            worker.start()
            worker.join()
            seen["inside"] = os.sched_getaffinity(0)
        seen["after"], seen["before"] = os.sched_getaffinity(0), before

    runner = threading.Thread(target=body)  # pin a thread of the test's own, not pytest's
    runner.start()
    runner.join()
    assert seen["inside"] == seen["child"] == {max(seen["before"])}
    assert seen["after"] == seen["before"]


@needs_affinity
def test_all_pins_nothing() -> None:
    before = os.sched_getaffinity(0)
    with pinned("all") as cpus:
        assert cpus is None and os.sched_getaffinity(0) == before
