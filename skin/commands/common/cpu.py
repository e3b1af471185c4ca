"""``--cpu``: run a command's threads on chosen CPUs (Linux's ``sched_setaffinity``).

Every thread of the host (python-can's notifier, the data plane's publisher, the SYNC
producer, canopen's heartbeats) runs Python and so holds the one GIL in turn: they never
run at once, and a cycle is a chain of hand-offs between them. On one CPU each hand-off
wakes a thread on the core whose caches hold the cycle's data, with no inter-processor
interrupt; spread over several, each wakes on whichever core is free and starts cold.
``skin demo --patches 8`` measured 1.2 to 1.5 ms p99 on one CPU against 1.7 to 2.0 ms
spread over two (docs/host.md, "Figures").

Pinning is done before the command starts any thread: threads inherit the affinity of
the thread that creates them (Linux pins the calling thread, not the whole process).
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Iterator
from contextlib import contextmanager

from skin.errors import ConfigError

MAX_CPU = 4095
ALL = "all"
LAST = "last"


def add_cpu_argument(parser: argparse.ArgumentParser, default: str) -> None:
    parser.add_argument(
        "--cpu", default=default, metavar="CPUS",
        help="run every thread on these CPUs: a list like 3 or 0,2-3, 'last' (the "
             "highest-numbered CPU this process may use) or 'all' (no pinning) "
             f"(default {default})")


def parse_cpus(spec: str, allowed: set[int]) -> set[int] | None:
    """``spec`` -> the CPUs to run on, None for no pinning; a CPU outside ``allowed`` is
    refused, naming it."""
    text = spec.strip().lower()
    if text == ALL:
        return None
    if text == LAST:
        return {max(allowed)}
    cpus: set[int] = set()
    for part in text.split(","):
        low, dash, high = part.partition("-")
        try:
            first, last = int(low), int(high if dash else low)
        except ValueError as err:
            raise ConfigError("--cpu", f"expected a list like 3 or 0,2-3, 'last' or 'all', "
                              f"got {spec!r}") from err
        if first < 0 or last < first or last > MAX_CPU:
            raise ConfigError("--cpu", f"{part!r} is not a CPU range (CPUs 0..{MAX_CPU})")
        cpus.update(range(first, last + 1))
    outside = sorted(cpus - allowed)
    if outside:
        raise ConfigError("--cpu", f"CPU(s) {', '.join(map(str, outside))} not available to "
                          f"this process (it may use {_ranges(allowed)})")
    return cpus


@contextmanager
def pinned(spec: str) -> Iterator[set[int] | None]:
    """Run the calling thread, and the threads it starts meanwhile, on the CPUs ``spec``
    names; yields them, or None when not pinned (``all``, or the default ``last`` on a
    platform without ``sched_setaffinity``: macOS, Windows). The calling thread's
    affinity is restored on exit."""
    getaffinity = getattr(os, "sched_getaffinity", None)
    setaffinity = getattr(os, "sched_setaffinity", None)
    if getaffinity is None or setaffinity is None:
        if spec.strip().lower() not in (ALL, LAST):
            raise ConfigError("--cpu", "this platform cannot pin threads to CPUs; use --cpu all")
        yield None
        return
    before = set(getaffinity(0))
    cpus = parse_cpus(spec, before)
    if cpus is None:
        yield None
        return
    setaffinity(0, cpus)
    try:
        yield cpus
    finally:
        setaffinity(0, before)


def _ranges(cpus: set[int]) -> str:
    out, ordered = [], sorted(cpus)
    start = prev = ordered[0]
    for cpu in [*ordered[1:], None]:
        if cpu is not None and cpu == prev + 1:
            prev = cpu
            continue
        out.append(str(start) if start == prev else f"{start}-{prev}")
        if cpu is not None:
            start = prev = cpu
    return ",".join(out)
