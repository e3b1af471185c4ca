"""Fail any test that leaves a python-can virtual or timed channel open (as python-can does)."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import can.interfaces.virtual
import pytest

from tests.support.rigs.dataplane import Host
from tests.support.rigs.host import Rig


@pytest.fixture(autouse=True)
def _no_open_virtual_channels() -> Iterator[None]:
    yield
    left = dict(can.interfaces.virtual.channels)
    can.interfaces.virtual.channels.clear()
    assert not left, f"test left virtual channels open: {sorted(map(str, left))}"


@pytest.fixture
def host() -> Iterator[Host]:
    """A data plane publishing to a sink bus, with patches 1 and 2 (rigs.dataplane)."""
    h = Host()
    yield h
    h.close()


@pytest.fixture(autouse=True)
def _no_open_timed_channels() -> Iterator[None]:
    """Fail a test that leaves a timed channel open (its wire's thread would run on)."""
    yield
    from canbus.timed.channels import close_all

    left = close_all()
    wire_threads = [t.name for t in threading.enumerate() if t.name.startswith("timed wire")]
    assert not left, f"test left timed channels open: {sorted(map(str, left))}"
    assert not wire_threads, f"timed wire threads still running: {wire_threads}"


@pytest.fixture
def rig(request: pytest.FixtureRequest) -> Iterator[Rig]:
    r = Rig(f"host-{request.node.name}")
    yield r
    r.close()
