"""``skin bench realtime``: the host beside CPU-bound work, with and without --realtime.

The shape of a robot PC: ``skin sim run`` serves N simulated 3-axis patches at 100 Hz on
udp_multicast (loopback), under SCHED_FIFO 60 where this process may grant it, since
hardware patches are never starved; K CPU-bound processes run beside the host; ``skin
run`` is the host, once at normal priority and once with ``--realtime`` (SCHED_FIFO 50);
a bare python-can receiver on the same bus (:mod:`skin.benchmarks.bare_receiver`, SCHED_FIFO
55 where granted, so that it misses no frame) takes every frame, the floor of the transport's cost,
and is the independent listener whose kernel stamps time the host's answers. Each run has
its own group and port.

Figures of each run, over a window of ``seconds`` that starts 2 s after every patch is
operational:

* ``complete_pct``: the host's steady state (``skin run --json``'s
  ``steady_complete_pct``: from the first cycle with every patch operational to the end);
  ``incomplete_pct_per_window``: the host's own 2 s status windows, ``max`` and ``p95``;
* ``sync_to_last_force_pdo_ms``: SYNC to the cycle's last force PDO as the listener's
  socket stamped both (p50, p99); ``last_patch_pdo_to_last_force_pdo_ms``: the host's own
  part, from the cycle's last patch PDO (the patches' part ends there);
* ``host_cpu_pct`` and ``host_cpu_us_per_frame``: the host process's CPU over the window,
  per frame that crossed the bus (every frame the listener took);
  ``bare_pycan_recv_cpu_us_per_frame``: the listener's own CPU per frame, same window;
  ``host_over_bare``: their ratio;
* ``sim_cpu_pct``, ``sim_realtime`` and ``host_realtime``: whether the priorities asked
  for were granted.
"""

from __future__ import annotations

import json
import os
import queue
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import IO, Any

import numpy as np

from canbus.busload import TPDO_BASES
from skin.benchmarks.proccpu import process_cpu_s
from skin.benchmarks.publish import free_udp_ports
from skin.errors import BusError

DEFAULT_PATCHES, DEFAULT_HOGS, DEFAULT_SECONDS = 8, 2, 20.0
SIM_PRIORITY, LISTENER_PRIORITY, HOST_PRIORITY = 60, 55, 50
"""The patches stand for hardware and the listener for the bus itself: neither may be what
starves (a listener that drops frames would undercount the bus)."""
STATUS_EVERY_S = 2.0
SETTLE_S = 2.0  # after every patch is operational, before the window opens
READY_TIMEOUT_S = 60.0
FORCE_NODE_OFFSET = 64
STATUS = re.compile(r"status: (\d+)/(\d+) patches operational, .*?([\d.]+) % incomplete")


def run_realtime_benchmark(patches: int = DEFAULT_PATCHES, hogs: int = DEFAULT_HOGS,
                           seconds: float = DEFAULT_SECONDS, *,
                           variants: tuple[bool, ...] = (False, True),
                           log: Any = print) -> dict[str, Any]:
    """One run per variant (``True``: the host with ``--realtime``); the figures."""
    runs = []
    for k, realtime in enumerate(variants):
        log(f"run {k + 1} of {len(variants)}: {patches} patches, {hogs} CPU-bound "
            f"process(es) beside the host, host {'--realtime' if realtime else 'normal'}")
        runs.append(_one_run(patches, hogs, seconds, realtime, k))
    return {"patches": patches, "hogs": hogs, "seconds": seconds, "rate_hz": 100.0,
            "cpu_count": os.cpu_count(), "runs": runs}


def _one_run(patches: int, hogs: int, seconds: float, realtime: bool,
             k: int) -> dict[str, Any]:
    group = f"239.75.{os.getpid() % 250}.{k % 250 + 1}"
    port = free_udp_ports(1)
    bus = ["-i", "udp_multicast", "-c", group, "--bus-kwargs", f"port={port}"]
    force = [f"{cob:X}" for n in range(1, patches + 1) for cob in _force_tpdos(n)]
    patch = [f"{base + n:X}" for n in range(1, patches + 1) for base in TPDO_BASES[:7]]
    with tempfile.TemporaryDirectory() as tmp, _Processes() as procs:
        config = Path(tmp) / "host.toml"
        config.write_text(_host_config(patches))
        out = Path(tmp) / "host.json"
        sim_realtime = procs.start(
            "sim", [sys.executable, "-m", "skin.cli", "-q", "sim", "run", "indenter",
                    "--patches", str(patches), *bus, "--seconds", str(10 * seconds + 600)],
            priority=SIM_PRIORITY)
        procs.start("listener", [sys.executable, "-m", "skin.benchmarks.bare_receiver", group,
                                 str(port), ",".join(force), ",".join(patch)],
                    priority=LISTENER_PRIORITY)
        procs.expect("listener", lambda line: line.startswith("{"), "ready")
        for h in range(hogs):
            procs.start(f"hog{h}", [sys.executable, "-c", "while True: pass"])
        host_cmd = [sys.executable, "-m", "skin.cli", "run", str(config), *bus, "--seconds",
                    str(seconds + READY_TIMEOUT_S), "--status-every", str(STATUS_EVERY_S),
                    "--json", str(out)]
        if realtime:
            host_cmd += ["--realtime", str(HOST_PRIORITY)]
        procs.start("host", host_cmd)
        procs.expect("host", lambda line: _all_operational(line, patches),
                     "every patch operational")
        time.sleep(SETTLE_S)
        start = _window_mark(procs)
        time.sleep(seconds)
        end = _window_mark(procs)
        windows = [float(m.group(3)) for line in procs.lines("host")
                   if (m := STATUS.search(line)) and _all_operational(line, patches)][1:]
        procs.signal("host", signal.SIGINT)
        procs.wait("host", READY_TIMEOUT_S)
        if not out.exists():
            raise BusError(f"skin run wrote no figures: {procs.tail('host')}")
        host = json.loads(out.read_text())
        host_realtime = not any("--realtime" in line and "not permitted" in line
                                for line in procs.lines("host"))
    return _figures(host, start, end, windows, realtime=realtime,
                    host_realtime=realtime and host_realtime, sim_realtime=sim_realtime)


def _figures(host: dict[str, Any], start: dict[str, Any], end: dict[str, Any],
             windows: list[float], *, realtime: bool, host_realtime: bool,
             sim_realtime: bool) -> dict[str, Any]:
    span = end["time"] - start["time"]
    frames = end["listener"]["frames"] - start["listener"]["frames"]
    host_cpu = end["host_cpu_s"] - start["host_cpu_s"]
    bare_cpu = end["listener"]["cpu_s"] - start["listener"]["cpu_s"]
    delays = np.asarray(end["listener"].get("sync_to_last_force_pdo_ms", []))
    host_part = list(end["listener"].get("last_patch_pdo_to_last_force_pdo_ms", []))
    per_frame = 1e6 * host_cpu / max(frames, 1)
    bare_per_frame = 1e6 * bare_cpu / max(frames, 1)
    stats = host["stats"]
    return {
        "realtime": realtime, "host_realtime": host_realtime, "sim_realtime": sim_realtime,
        "complete_pct": host["steady_complete_pct"],
        "steady_samples": stats["steady_samples"], "samples": stats["samples"],
        "late_frames": stats["late_frames"], "sync_overruns": stats["sync_overruns"],
        "mean_batch": stats["samples"] / max(stats["batches"], 1),
        "incomplete_pct_per_window": _spread(windows, ("max", "p95")),
        "sync_to_last_force_pdo_ms": _spread(list(delays), ("p50", "p99", "max")),
        "last_patch_pdo_to_last_force_pdo_ms": _spread(host_part, ("p50", "p99", "max")),
        "frames_per_s": frames / span,
        "host_cpu_pct": 100.0 * host_cpu / span,
        "host_cpu_us_per_frame": per_frame,
        "bare_pycan_recv_cpu_us_per_frame": bare_per_frame,
        "host_over_bare": per_frame / bare_per_frame if bare_per_frame else None,
        "sim_cpu_pct": 100.0 * (end["sim_cpu_s"] - start["sim_cpu_s"]) / span,
        "window_s": span,
    }


def _spread(values: list[float], keys: tuple[str, ...]) -> dict[str, float | None]:
    if not values:
        return dict.fromkeys(keys)
    a = np.asarray(values, dtype=float)
    pick = {"max": lambda: a.max(), "p50": lambda: np.percentile(a, 50),
            "p95": lambda: np.percentile(a, 95), "p99": lambda: np.percentile(a, 99)}
    return {k: round(float(pick[k]()), 4) for k in keys}


def _window_mark(procs: _Processes) -> dict[str, Any]:
    """Open or close the window: the listener's count and CPU, the host's and sim's CPU."""
    procs.signal("listener", signal.SIGUSR1)
    listener = json.loads(procs.expect("listener", lambda line: '"frames"' in line,
                                       "its count"))
    return {"time": listener["time"], "listener": listener,
            "host_cpu_s": procs.cpu_s("host"), "sim_cpu_s": procs.cpu_s("sim")}


def _all_operational(line: str, patches: int) -> bool:
    m = STATUS.search(line)
    return m is not None and int(m.group(1)) == int(m.group(2)) == patches


def _force_tpdos(patch: int) -> list[int]:
    """The default force node's TPDO COB-IDs (CiA 301's predefined set and 0x2xx-0x5xx
    continued as the force node lays them out)."""
    from canbus.master.forcenode import ForceNode

    node = ForceNode(patch + FORCE_NODE_OFFSET, patch, heartbeat_ms=0)
    return sorted(int(c) for c in node.tpdo.codec.cob_ids)


def _host_config(patches: int) -> str:
    lines = ["[host]", "sync_period_ms = 10.0", ""]
    for n in range(1, patches + 1):
        lines += ["[[patches]]", f"node_id = {n}", ""]
    return "\n".join(lines)


class _Processes:
    """Child processes, their output lines read as they come, all ended on exit."""

    def __init__(self) -> None:
        self._procs: dict[str, subprocess.Popen[str]] = {}
        self._lines: dict[str, list[str]] = {}
        self._queues: dict[str, queue.Queue[str]] = {}

    def __enter__(self) -> _Processes:
        return self

    def __exit__(self, *exc: object) -> None:
        for proc in self._procs.values():
            if proc.poll() is None:
                proc.kill()
        for proc in self._procs.values():
            proc.wait()

    def start(self, name: str, cmd: list[str], *, priority: int | None = None) -> bool:
        """Start ``cmd``; True if it runs under SCHED_FIFO ``priority`` as asked."""
        granted = priority is not None and _may_realtime(priority)

        def preexec() -> None:
            if granted:
                assert priority is not None
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))

        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True, preexec_fn=preexec)
        self._procs[name], self._lines[name] = proc, []
        self._queues[name] = queue.Queue()
        assert proc.stdout is not None
        threading.Thread(target=self._read, args=(name, proc.stdout), daemon=True).start()
        return granted

    def _read(self, name: str, stream: IO[str]) -> None:
        for line in stream:
            self._lines[name].append(line.rstrip("\n"))
            self._queues[name].put(line)

    def expect(self, name: str, match: Any, what: str) -> str:
        deadline = time.monotonic() + READY_TIMEOUT_S
        while time.monotonic() < deadline:
            try:
                line = self._queues[name].get(timeout=0.2)
            except queue.Empty:
                if self._procs[name].poll() is not None:
                    break
                continue
            if match(line):
                return line
        raise BusError(f"{name}: no {what} within {READY_TIMEOUT_S:g} s: {self.tail(name)}")

    def lines(self, name: str) -> list[str]:
        return list(self._lines[name])

    def tail(self, name: str) -> str:
        return " | ".join(self._lines[name][-5:]) or "(no output)"

    def signal(self, name: str, signum: int) -> None:
        self._procs[name].send_signal(signum)

    def wait(self, name: str, timeout: float) -> None:
        self._procs[name].wait(timeout)

    def cpu_s(self, name: str) -> float:
        """The process's user and system CPU time so far (all its threads)."""
        return process_cpu_s(self._procs[name].pid)


def _may_realtime(priority: int) -> bool:
    """Whether this process may give a child SCHED_FIFO ``priority``."""
    try:
        before = (os.sched_getscheduler(0), os.sched_getparam(0))
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (AttributeError, PermissionError):
        return False
    os.sched_setscheduler(0, *before)
    return True
