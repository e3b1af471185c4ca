"""Where the CPU of ``skin bench publish`` went, and whether the machine carried the shape.

Each process of the shape (the H hosts, the simulator, the reader) is a :class:`Role`: the
CPU it used over the measured window, in percent of one core, and the CPU it needs at the
shape's full rate, scaled from its measured cost per unit of work (a host's and the
simulator's per bus frame, the reader's per sample) to the work the shape makes at that
rate. A machine that cannot keep up runs fewer SYNC cycles than the rate asks for, so the
need is above what was measured; on a machine that keeps up the two are the same.

:func:`verdict` says the shape does not fit the machine when

* a process needs (or used) at least :data:`PROCESS_LIMIT_PCT` of one core: a Python
  process runs its Python code on one core at a time (the GIL), and with less than a tenth
  of a core left it has no slack for a cycle whose work comes late;
* the processes together need at least :data:`MACHINE_LIMIT` of the machine's cores: on
  the 2-core machine of docs/zenoh.md, shapes that needed up to 60 % of it carried every
  sample, from 65 % on they lost some on the CAN side: seven processes share the cores,
  each with its part of every 10 ms cycle to do, and the fuller the cores, the longer a
  process waits for one;
* other work than the bench's processes took at least :data:`OTHER_LIMIT` of the
  machine's cores, and with it the machine was asked for at least :data:`MACHINE_LIMIT`
  of its cores: the shape then got less than it needed, whatever it needs.

In every one of these cases the complete shares measure the machine, not Zenoh.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

PROCESS_LIMIT_PCT = 90.0
MACHINE_LIMIT = 0.6
OTHER_LIMIT = 0.1


@dataclass(frozen=True)
class Role:
    """One process of the shape over the measured window."""

    name: str
    cpu_pct: float
    """The CPU it used, in percent of one core."""
    need_pct: float | None
    """The CPU it needs at the shape's full rate, in percent of one core; None: it did no
    work in the window to scale from."""

    @property
    def demand_pct(self) -> float:
        """What it needs, or what it used if more (a run faster than the rate)."""
        return max(self.cpu_pct, self.need_pct or 0.0)


@dataclass(frozen=True)
class Verdict:
    fits: bool
    why: str
    """One line: what does not fit, or what the shape needs of what the machine has."""


def verdict(roles: Sequence[Role], capacity_pct: float, machine_busy_pct: float) -> Verdict:
    """Whether the machine (``capacity_pct``: 100 per usable core) carried the shape."""
    if not roles or capacity_pct <= 0:
        raise ValueError("a verdict needs at least one process and a positive capacity")
    reasons = [f"{r.name} did no work in the window" for r in roles if r.need_pct is None]
    reasons += [f"{r.name} needs {r.demand_pct:.0f} % of a core (a process has "
                f"{PROCESS_LIMIT_PCT:.0f} % of one)"
                for r in roles if r.demand_pct >= PROCESS_LIMIT_PCT]
    need = sum(r.demand_pct for r in roles)
    usable = MACHINE_LIMIT * capacity_pct
    if need >= usable:
        reasons.append(f"the processes need {need:.0f} % of a core in all, the machine has "
                       f"{capacity_pct:.0f} % ({100 * MACHINE_LIMIT:.0f} % of it usable)")
    other = machine_busy_pct - sum(r.cpu_pct for r in roles)
    if other >= OTHER_LIMIT * capacity_pct and need + other >= usable:
        reasons.append(f"the machine was shared: other work took {other:.0f} % of a core, "
                       f"and with it {need + other:.0f} % of the machine's "
                       f"{capacity_pct:.0f} % was asked for")
    if reasons:
        return Verdict(False, "; ".join(reasons))
    busiest = max(roles, key=lambda r: r.demand_pct)
    return Verdict(True, f"the processes need {need:.0f} % of a core in all, of the "
                         f"machine's {capacity_pct:.0f} %; the busiest, {busiest.name}, "
                         f"{busiest.demand_pct:.0f} %")


def _per_s(count: float, seconds: float) -> float:
    return count / seconds if seconds > 0 else 0.0


def _need(us_per_unit: float | None, units_per_s: float) -> float | None:
    return None if us_per_unit is None else us_per_unit * units_per_s / 1e4


def cpu_figures(windows: Sequence[dict[str, Any]], reader: dict[str, Any],
                reader_samples: int, simulator_cpu_s: float, span_s: float,
                machine_busy_pct: float, cores: int, patches: int,
                rate_hz: float) -> tuple[dict[str, Any], Verdict]:
    """The ``cpu`` figures of the run (each role's CPU, cost per unit of work and need)
    and the verdict on them.

    ``windows`` are the hosts' (CPU, seconds, bus frames received and sent, SYNC cycles),
    ``reader`` the reader's (CPU, seconds) and ``reader_samples`` the samples it received of
    the window's cycles; the simulator's CPU and the machine's busy share are over the
    runner's window of ``span_s``.
    """
    hosts_pct, host_us, host_frames_s, host_need, full_frames_s = [], [], [], [], 0.0
    per_cycle: list[float | None] = []
    for window in windows:
        frames = window["frames_received"] + window["frames_sent"]
        cycles = window["last_cycle"] - window["first_cycle"] + 1
        per_cycle.append(frames / cycles if cycles > 0 else None)
        full = None if per_cycle[-1] is None else per_cycle[-1] * rate_hz  # at the rate
        us = 1e6 * window["cpu_s"] / frames if frames else None
        hosts_pct.append(100.0 * _per_s(window["cpu_s"], window["seconds"]))
        host_us.append(us)
        host_frames_s.append(_per_s(frames, window["seconds"]))
        host_need.append(None if full is None else _need(us, full))
        full_frames_s += full or 0.0
    simulator_pct = 100.0 * _per_s(simulator_cpu_s, span_s)
    frames_s = sum(host_frames_s)
    simulator_us = 1e4 * simulator_pct / frames_s if frames_s else None
    reader_pct = 100.0 * _per_s(reader["cpu_s"], reader["seconds"])
    reader_us = 1e6 * reader["cpu_s"] / reader_samples if reader_samples else None
    roles = [*(Role(f"host{k}", pct, need)
               for k, (pct, need) in enumerate(zip(hosts_pct, host_need, strict=True))),
             Role("simulator", simulator_pct, _need(simulator_us, full_frames_s)),
             Role("reader", reader_pct, _need(reader_us, patches * rate_hz))]
    total = sum(r.cpu_pct for r in roles)
    return {
        "cores": cores, "capacity_pct": 100.0 * cores, "hosts_pct": hosts_pct,
        "simulator_pct": simulator_pct, "reader_pct": reader_pct, "total_pct": total,
        "machine_busy_pct": machine_busy_pct, "other_pct": machine_busy_pct - total,
        "host_frames_per_s": host_frames_s, "host_frames_per_cycle": per_cycle,
        "host_us_per_frame": host_us,
        "simulator_us_per_frame": simulator_us, "reader_us_per_sample": reader_us,
        "need_pct": {"hosts": host_need, "simulator": roles[-2].need_pct,
                     "reader": roles[-1].need_pct,
                     "total": sum(r.demand_pct for r in roles)},
    }, verdict(roles, 100.0 * cores, machine_busy_pct)
