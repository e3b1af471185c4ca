"""Settings for the whole suite: Hypothesis profiles, ports, child processes (docs/testing.md)."""

from __future__ import annotations

import os
import signal
from collections.abc import Generator, Iterator

import pytest
from hypothesis import HealthCheck, settings

from tests.support.rigs import children, ports

# Hypothesis' per-example deadline (200 ms) and its too_slow health check are speed tests in
# disguise: on a busy two-core machine a fine example can take longer. Speed is measured by
# benchmarks, not by tests. CI (.ci/run sets CANSKIN_HYPOTHESIS_PROFILE=ci) runs the same
# examples every time, with no example database: a red run is reproducible from its log.
_COMMON = {"deadline": None, "suppress_health_check": [HealthCheck.too_slow]}
settings.register_profile("dev", **_COMMON)
settings.register_profile("ci", derandomize=True, database=None, print_blob=True, **_COMMON)
settings.load_profile(os.environ.get("CANSKIN_HYPOTHESIS_PROFILE", "dev"))


def pytest_configure(config: pytest.Config) -> None:
    """The stop signals act as on a terminal however the suite was started: a shell without
    job control starts a background command (``.ci/run &``) with SIGINT ignored, ``nohup``
    ignores SIGHUP, and a command leaves a signal it was started ignoring ignored
    (``skin.commands.common.signals``), so the tests that stop a command as a user does
    would wait for ever. Children started from here get them back as well."""
    defaults = {signal.SIGINT: signal.default_int_handler, signal.SIGHUP: signal.SIG_DFL,
                signal.SIGTERM: signal.SIG_DFL}
    for sig, handler in defaults.items():
        if signal.getsignal(sig) is signal.SIG_IGN:
            signal.signal(sig, handler)


@pytest.fixture
def udp_bus() -> tuple[str, int]:
    """A multicast group and UDP port no other test uses, here or in another process
    (tests/support/rigs/ports.py): a udp_multicast bus of the test's own."""
    return ports.udp_bus()


@pytest.fixture
def udp_channel(udp_bus: tuple[str, int]) -> str:
    """The group of the test's own udp_multicast bus (its port: ``udp_port``)."""
    return udp_bus[0]


@pytest.fixture
def udp_port(udp_bus: tuple[str, int]) -> int:
    """The port of the test's own udp_multicast bus (its group: ``udp_channel``)."""
    return udp_bus[1]


@pytest.fixture(autouse=True)
def _children_end_with_the_test() -> Iterator[None]:
    """Every child process a test started (tests/support/rigs/children.py) has ended when it ends:
    one still running is killed and fails the test."""
    children.started.clear()
    yield
    left = children.reap()
    assert not left, (
        "the test left child processes running (killed now); stop each before the test "
        "ends (Child.stop / Child.wait, or a finally):\n"
        + "\n".join(child.output() for child in left))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item,
                              call: pytest.CallInfo[None]) -> Generator[None, None, None]:
    """A failed test (a timeout too) shows the output of every child it started, the ones
    still running killed first."""
    outcome = yield
    report = outcome.get_result()
    if report.when == "call" and report.failed and children.started:
        children.reap()
        for child in children.started:
            report.sections.append((f"child pid {child.pid}", child.output()))


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The documentation's test first: its documents run for minutes in a pool of their own,
    so with two workers (a test file each) the other files run beside it, not after it."""
    items.sort(key=lambda item: item.path.name != "test_docs.py")
