"""Waiting for something to happen, with a deadline: the one place tests and rigs sleep.

A fixed ``time.sleep`` before an assert is a guess at how long something takes: too short on
a busy machine (a red run), too long everywhere else (a slow suite). Wait for the event
itself (a state, a frame, a line, a file) with :func:`wait_until`; it polls the condition
and fails, saying what did not happen, when the deadline passes. The deadline is generous
on purpose: it only bounds a failure, a passing run never waits for it.

``tests/test_suite_rules.py`` allows ``time.sleep`` only here and on a line marked
``# pacing: <why>`` (a sender keeping a rate, a run kept going for a span of traffic):
never to wait for something to happen.

    wait_until(lambda: node.nmt.state == "OPERATIONAL", what="the node is operational")
    frame = wait_until(lambda: reader.latest(), what="a force frame")
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")

DEADLINE_S = 30.0
"""The default deadline: far beyond any wait of a passing run, even on a loaded machine."""


def wait_until(condition: Callable[[], T], *, what: str, timeout: float = DEADLINE_S,
               interval: float = 0.005) -> T:
    """Poll ``condition`` every ``interval`` s until it returns a true value, and return
    that value; AssertionError naming ``what`` once ``timeout`` s passed without one."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout} s")
        time.sleep(interval)


def holds_for(condition: Callable[[], object], seconds: float, *, what: str,
              interval: float = 0.005) -> None:
    """Check that ``condition`` stays true for ``seconds`` (something that must NOT happen
    does not, over a span): AssertionError naming ``what`` at the first false."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        assert condition(), what
        time.sleep(interval)
