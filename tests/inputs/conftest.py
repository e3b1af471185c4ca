"""The hostile-input suite (issue 21): broken files and values of every kind, generated.

Examples per test are fixed (derandomized: the same cases every run) and kept small, so
the whole suite costs about a minute; ``SKIN_HOSTILE_EXAMPLES`` multiplies them for a
longer hunt, and ``SKIN_HOSTILE_RANDOM=1`` draws new cases each run. The memory budget
is held at 256 MiB (``SKIN_MEMORY_BUDGET``) so a declared size is refused long before it
could hurt the machine.
"""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, settings

from tests.canbus.conftest import _no_open_virtual_channels

__all__ = ["_no_open_virtual_channels", "examples"]

SCALE = int(os.environ.get("SKIN_HOSTILE_EXAMPLES", "1"))
RANDOM = os.environ.get("SKIN_HOSTILE_RANDOM") == "1"


def examples(n: int) -> settings:
    """Hypothesis settings for ``n`` examples (times SKIN_HOSTILE_EXAMPLES), derandomized."""
    return settings(max_examples=n * SCALE, derandomize=not RANDOM, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow, HealthCheck.data_too_large])


@pytest.fixture(autouse=True)
def _small_memory_budget(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SKIN_MEMORY_BUDGET", "256M")
