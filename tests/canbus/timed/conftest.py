"""Helpers for the timed bus tests: a channel per test and buses closed after it."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from canbus.timed import TimedBus

_names = itertools.count()
OpenBus = Callable[..., TimedBus]


@pytest.fixture
def channel() -> str:
    return f"timed-test-{next(_names)}"


@pytest.fixture
def open_bus(channel: str) -> Iterator[OpenBus]:
    """``open_bus(**kwargs)``: a TimedBus on this test's channel, shut down after the test.

    Simulated time unless ``realtime=True`` is given."""
    buses: list[TimedBus] = []

    def make(**kwargs: Any) -> TimedBus:
        kwargs.setdefault("realtime", False)
        bus = TimedBus(kwargs.pop("channel", channel), **kwargs)
        buses.append(bus)
        return bus

    yield make
    for bus in buses:
        bus.shutdown()
