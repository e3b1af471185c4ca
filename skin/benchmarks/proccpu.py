"""CPU time as Linux's ``/proc`` counts it: one process's (all its threads), and the whole
machine's busy and total time, so that a benchmark can say where the CPU of a window went.

The machine's figures come from the first line of ``/proc/stat`` (every CPU summed, in
clock ticks): busy is everything but ``idle`` and ``iowait``; ``guest`` time is already in
``user`` and is not counted twice. A share of the machine is given in percent of one core,
like a process's: two busy cores are 200 %.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from skin.errors import BusError


def process_cpu_s(pid: int) -> float:
    """The user and system CPU time of process ``pid`` so far (all its threads)."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text(encoding="ascii")
    except OSError as err:
        raise BusError(f"no CPU time for process {pid}: {err}") from err
    utime, stime = text.rsplit(")", 1)[1].split()[11:13]  # fields 14 and 15 of proc(5)
    return (int(utime) + int(stime)) / os.sysconf("SC_CLK_TCK")


@dataclass(frozen=True)
class MachineTicks:
    """The machine's CPU time so far, every CPU summed, in clock ticks."""

    busy: int
    total: int
    cpus: int
    """The CPUs ``/proc/stat`` counts (``cpuN`` lines)."""


def machine_ticks(stat: str | None = None) -> MachineTicks:
    """Read ``/proc/stat`` (or the text ``stat``)."""
    text = Path("/proc/stat").read_text(encoding="ascii") if stat is None else stat
    lines = text.splitlines()
    if not lines or lines[0].split()[0] != "cpu":
        raise ValueError("/proc/stat: the first line is not the 'cpu' total")
    fields = [int(v) for v in lines[0].split()[1:]] + [0] * 8  # older kernels: fewer
    user, nice, system, idle, iowait, irq, softirq, steal = fields[:8]
    cpus = sum(1 for line in lines[1:] if line.startswith("cpu") and line[3:4].isdigit())
    total = user + nice + system + idle + iowait + irq + softirq + steal
    return MachineTicks(busy=total - idle - iowait, total=total, cpus=max(cpus, 1))


def busy_pct(start: MachineTicks, end: MachineTicks) -> float:
    """How busy the machine was between two readings, in percent of one core."""
    span = end.total - start.total
    return 100.0 * end.cpus * (end.busy - start.busy) / span if span > 0 else 0.0


def usable_cores() -> int:
    """The CPUs this process (and the children it starts) may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1
