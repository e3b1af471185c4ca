"""Fail any test that leaves a python-can virtual channel open (as python-can's suite does)."""

from __future__ import annotations

import itertools
import os
from collections.abc import Iterator

import can.interfaces.virtual
import pytest

_ports = itertools.count(43000 + (os.getpid() % 1000) * 16)


@pytest.fixture(autouse=True)
def _no_open_virtual_channels() -> Iterator[None]:
    yield
    left = dict(can.interfaces.virtual.channels)
    can.interfaces.virtual.channels.clear()
    assert not left, f"test left virtual channels open: {sorted(map(str, left))}"


@pytest.fixture
def udp_channel() -> str:
    """A multicast group:port on loopback unique to this test."""
    return f"239.74.{os.getpid() % 250}.{next(_ports) % 250 + 1}"
