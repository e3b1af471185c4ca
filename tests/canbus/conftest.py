"""Fail any test that leaves a python-can virtual or timed channel open (as python-can does)."""

from __future__ import annotations

import itertools
import os
import threading
from collections.abc import Iterator

import can.interfaces.virtual
import pytest

from bench.rigs.dataplane import Host

_groups = itertools.count(43000 + (os.getpid() % 1000) * 16)
_udp_ports = itertools.count(20000 + (os.getpid() % 750) * 16)  # below Linux's ephemeral ports


@pytest.fixture(autouse=True)
def _no_open_virtual_channels() -> Iterator[None]:
    yield
    left = dict(can.interfaces.virtual.channels)
    can.interfaces.virtual.channels.clear()
    assert not left, f"test left virtual channels open: {sorted(map(str, left))}"


@pytest.fixture
def udp_channel() -> str:
    """A multicast group on loopback unique to this test."""
    return f"239.74.{os.getpid() % 250}.{next(_groups) % 250 + 1}"


@pytest.fixture
def udp_port() -> int:
    """A UDP port unique to this test: Linux hands a socket every group joined on its port,
    so tests, and two suites running at once, keep apart by port as well as by group."""
    return next(_udp_ports)


@pytest.fixture
def host() -> Iterator[Host]:
    """A data plane publishing to a sink bus, with patches 1 and 2 (bench.rigs.dataplane)."""
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
