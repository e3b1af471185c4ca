"""Settings for the whole suite."""

from __future__ import annotations

from hypothesis import settings

# Hypothesis' per-example deadline (200 ms) is a speed test in disguise: on a busy two-core
# machine a fine example can take longer. Speed is measured by benchmarks, not by tests.
settings.register_profile("canskin", deadline=None)
settings.load_profile("canskin")
