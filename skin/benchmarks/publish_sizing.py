"""The CPU a skin's shape needs, from runs of ``skin bench publish``: size a robot.

Part of a process's work is per SYNC cycle whatever the patches (waking, the SYNC, a
batch decoded and published), the rest per frame or per sample; so each role's cost is a
fixed part and a part per unit of work (:class:`Cost`), fitted by least squares over runs
that differ in patches per bus (:func:`costs_from_runs`):

* a host: microseconds per SYNC cycle of its bus = fixed + per frame x the bus's frames
  per cycle;
* the simulator (the bench's stand-in for the patches): the same, for each bus it serves;
* the reader: microseconds per second = fixed + per sample x samples per second.

:func:`shape_needs` applies them to any shape (patches, buses, rate), counting each bus's
frames per cycle as :func:`canbus.busload.plan` counts them from the EDS mapping (3-axis
patches, force PDOs on the patch's bus with the contact summary, heartbeats every second
as the bench's hosts set them), and finds the fewest cores that carry it by
:func:`skin.benchmarks.publish_fit.verdict`'s limits.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from canbus.busload import plan
from skin.benchmarks.publish_fit import PROCESS_LIMIT_PCT, Role, verdict

MODE = "xyz"
HEARTBEAT_MS = 1000


@dataclass(frozen=True)
class Cost:
    """A role's CPU in microseconds: ``fixed_us`` plus ``per_unit_us`` per unit of work."""

    fixed_us: float
    per_unit_us: float

    def at(self, units: float) -> float:
        return self.fixed_us + self.per_unit_us * units


@dataclass(frozen=True)
class Costs:
    host: Cost
    """Per SYNC cycle of the host's bus; a unit is a frame on that bus."""
    simulator: Cost
    """Per SYNC cycle of each bus it serves; a unit is a frame on that bus."""
    reader: Cost
    """Per second; a unit is a sample a second."""


def _fit(points: Sequence[tuple[float, float]], role: str) -> Cost:
    x = np.array([p[0] for p in points])
    if len(np.unique(x)) < 2:
        raise ValueError(f"the {role}'s cost needs runs with two or more different "
                         f"{'samples a second' if role == 'reader' else 'patches per bus'}")
    per_unit, fixed = np.polyfit(x, np.array([p[1] for p in points]), 1)
    return Cost(float(fixed), float(per_unit))


def costs_from_runs(runs: Sequence[Mapping[str, Any]]) -> Costs:
    """Each role's :class:`Cost` from the JSON of runs of ``skin bench publish``, each
    process's need at the run's rate (``cpu.need_pct``) against its work."""
    host, simulator, reader = [], [], []
    for run in runs:
        cpu, rate = run["cpu"], run["rate_hz"]
        frames = cpu["host_frames_per_cycle"]
        host += [(f, 1e4 * need / rate) for f, need in zip(frames, cpu["need_pct"]["hosts"],
                                                              strict=True)
                 if f is not None and need is not None]
        measured = [f for f in frames if f is not None]
        if measured and cpu["need_pct"]["simulator"] is not None:
            simulator.append((sum(measured) / len(measured),
                              1e4 * cpu["need_pct"]["simulator"] / rate / len(measured)))
        if cpu["need_pct"]["reader"] is not None:
            reader.append((run["patches"] * rate, 1e4 * cpu["need_pct"]["reader"]))
    return Costs(_fit(host, "host"), _fit(simulator, "simulator"), _fit(reader, "reader"))


@dataclass(frozen=True)
class ShapeNeed:
    """What a shape needs, in percent of one core."""

    hosts_pct: tuple[float, ...]
    simulator_pct: float
    """0 for a robot (``simulated=False``)."""
    reader_pct: float
    cores: int | None
    """The fewest cores that carry it; None: a process alone needs too much of its core
    (more buses, fewer patches on each)."""

    @property
    def total_pct(self) -> float:
        return sum(self.hosts_pct) + self.simulator_pct + self.reader_pct


def bus_frames_per_cycle(patches: int, buses: int, rate_hz: float) -> list[float]:
    """Each bus's frames per SYNC cycle, patches 1..N spread in node order (the bench's)."""
    shape = plan(patches, rate_hz, MODE, 1_000_000, buses=buses, heartbeat_ms=HEARTBEAT_MS)
    return [sum(bus.frames_per_s.values()) / rate_hz for bus in shape.buses]


def shape_needs(costs: Costs, patches: int, buses: int, rate_hz: float, *,
                simulated: bool = True) -> ShapeNeed:
    """The CPU ``patches`` patches on ``buses`` buses (a host each) need at ``rate_hz``;
    ``simulated=False``: the patches are hardware, no simulator runs (a robot)."""
    frames = bus_frames_per_cycle(patches, buses, rate_hz)
    hosts = tuple(costs.host.at(f) * rate_hz / 1e4 for f in frames)
    simulator = sum(costs.simulator.at(f) for f in frames) * rate_hz / 1e4 if simulated \
        else 0.0
    reader = costs.reader.at(patches * rate_hz) / 1e4
    roles = [*(Role(f"host{k}", pct, pct) for k, pct in enumerate(hosts)),
             *([Role("simulator", simulator, simulator)] if simulated else []),
             Role("reader", reader, reader)]
    total = sum(hosts) + simulator + reader
    if any(r.demand_pct >= PROCESS_LIMIT_PCT for r in roles):
        return ShapeNeed(hosts, simulator, reader, None)
    cores = next(n for n in itertools.count(1) if verdict(roles, 100.0 * n, total).fits)
    return ShapeNeed(hosts, simulator, reader, cores)
