"""``skin bench publish``: H host processes publishing on Zenoh, one reader, on loopback.

The shape of a skin past one bus: ``skin sim run`` serves N simulated patches (3-axis,
100 Hz, ``indenter`` scene) spread over H udp_multicast buses (one group, H ports, all on
loopback); H host processes (:mod:`skin.benchmarks.publish_host`) each run a ``HostManager`` on
one bus and publish on Zenoh, listening on a TCP port of 127.0.0.1 of their own; one
reader process (:mod:`skin.benchmarks.publish_reader`) connects to all of them, multicast scouting
off, and subscribes to the whole skin. After every host is operational and the reader has
heard every host, a window of ``seconds`` is measured:

* ``reader_complete_pct``: of the (patch, SYNC) samples the hosts made in the window
  (every patch, every SYNC cycle from the window's first to its last), the share the
  reader received complete; ``host_complete_pct`` is the hosts' own share (CAN side);
* ``latency_ms``: SYNC (the host's ``time.time()`` as it sent it) to the reader's
  callback, over the window's samples; ``pdo_latency_ms``: SYNC to the host handing the
  sample out, right after its force TPDOs went onto the bus (``bus.send`` returned: on
  loopback UDP the datagram is then in every receiver's queue); both on one clock;
* ``publish_cpu_us_per_sample``: the host's CPU spent publishing on Zenoh (its
  publishing thread, Zenoh's own threads, the hand-over on the data plane's thread) per
  sample; ``host_cpu_us_per_sample``: the host process's whole CPU per sample;
* the reader's CPU, the machine's load average, and the two candidate encodings of a
  sample measured in the same run (:mod:`skin.benchmarks.codecs`);
* ``cpu``: where the CPU of the window went (each host, the simulator, the reader, the
  whole machine) and what each needs at 100 Hz; ``fits_machine`` and ``why``: whether the
  machine carried the shape (:mod:`skin.benchmarks.publish_fit`). When it did not, the complete
  shares measure the machine, not Zenoh.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from skin.benchmarks.codecs import measure_codecs
from skin.benchmarks.proccpu import busy_pct, machine_ticks, process_cpu_s, usable_cores
from skin.benchmarks.publish_fit import cpu_figures
from skin.benchmarks.publish_host import host_main, receive, send
from skin.benchmarks.publish_reader import reader_main
from skin.errors import BusError

DEFAULT_HOSTS, DEFAULT_PATCHES, DEFAULT_SECONDS = 4, 32, 10.0
WARMUP_S = 2.0
DRAIN_S = 0.5
SCENE = "indenter"
RATE_HZ = 100.0
READY_TIMEOUT_S = 120.0


def free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def free_udp_ports(count: int) -> int:
    """The first of ``count`` consecutive UDP ports free now (below the ephemeral range)."""
    base = 21000 + (os.getpid() % 400) * 20
    for start in range(base, 32000 - count, count):
        try:
            with contextlib.ExitStack() as stack:
                for port in range(start, start + count):
                    s = stack.enter_context(socket.socket(socket.AF_INET, socket.SOCK_DGRAM))
                    s.bind(("0.0.0.0", port))
            return start
        except OSError:
            continue
    raise OSError(f"no {count} consecutive free UDP ports")


def spread(patches: int, hosts: int) -> list[list[int]]:
    """Node-IDs 1..patches in node order over ``hosts`` buses (as ``skin sim run --buses``)."""
    sizes = [patches // hosts + (k < patches % hosts) for k in range(hosts)]
    out, first = [], 1
    for size in sizes:
        out.append(list(range(first, first + size)))
        first += size
    return out


def run_publish_benchmark(hosts: int = DEFAULT_HOSTS, patches: int = DEFAULT_PATCHES,
                          seconds: float = DEFAULT_SECONDS, *, express: bool = False,
                          log: Any = print) -> dict[str, Any]:
    """Run the benchmark (module docstring); the figures."""
    codecs = measure_codecs()
    group = f"239.74.{os.getpid() % 250}.{(os.getpid() // 250) % 250 + 1}"
    port = free_udp_ports(hosts)
    endpoints = [f"tcp/127.0.0.1:{free_tcp_port()}" for _ in range(hosts)]
    load_before = os.getloadavg()
    with _processes(hosts, patches, seconds, group, port, endpoints, express) as (
            sim, host_conns, reader_conn):
        log(f"{hosts} hosts, {patches} patches on udp_multicast {group} ports {port}.."
            f"{port + hosts - 1}; Zenoh on {', '.join(endpoints)}")
        for k, conn in enumerate(host_conns):
            ready = _wait(conn, f"host {k}")
            if not ready["ready"]:
                ended = "" if sim.poll() is None else \
                    f"; skin sim run ended: {sim.stderr.read().decode() if sim.stderr else ''}"
                raise BusError(f"host {k}: patches not operational: {ready['health']}"
                                   f"{ended}")
        heard = _wait(reader_conn, "the reader")
        if not heard["ready"]:
            raise BusError(f"the reader heard only {heard['heard']}")
        time.sleep(WARMUP_S)
        log(f"measuring {seconds:g} s")
        for conn in [*host_conns, reader_conn]:
            send(conn, {"measure": True})
        start = _runner_mark(sim)
        time.sleep(seconds)
        for conn in host_conns:
            send(conn, {"stop": True})
        end = _runner_mark(sim)
        time.sleep(DRAIN_S)
        send(reader_conn, {"stop": True})
        windows = [_wait(conn, f"host {k}") for k, conn in enumerate(host_conns)]
        reader = _wait(reader_conn, "the reader")
    load_after = os.getloadavg()
    result = summarize(windows, reader, patches)
    cpu, judged = cpu_figures(
        windows, reader, result["reader_samples"], end["sim_cpu_s"] - start["sim_cpu_s"],
        end["wall"] - start["wall"], busy_pct(start["machine"], end["machine"]),
        usable_cores(), patches, RATE_HZ)
    result.update(seconds=seconds, express=express, scene=SCENE, rate_hz=RATE_HZ,
                  cpu=cpu, fits_machine=judged.fits, why=judged.why,
                  codec=codecs, cpu_count=os.cpu_count(),
                  load_average={"before": list(load_before), "after": list(load_after)})
    return result


@contextlib.contextmanager
def _processes(hosts: int, patches: int, seconds: float, group: str, port: int,
               endpoints: list[str], express: bool
               ) -> Iterator[tuple[subprocess.Popen[bytes], list[Connection], Connection]]:
    ctx = mp.get_context("spawn")
    sim = subprocess.Popen(
        [sys.executable, "-m", "skin.cli", "-q", "sim", "run", SCENE, "--patches",
         str(patches), "--buses", str(hosts), "-i", "udp_multicast", "-c", group,
         "--bus-kwargs", f"port={port}", "--seconds", str(seconds + READY_TIMEOUT_S)],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    workers: list[Any] = []
    conns: list[Connection] = []
    try:
        for k, ids in enumerate(spread(patches, hosts)):
            ours, theirs = ctx.Pipe()
            proc = ctx.Process(target=host_main, name=f"bench-host{k}", daemon=True,
                               args=(theirs, k, group, port + k, ids, endpoints[k], express))
            proc.start()
            workers.append(proc)
            conns.append(ours)
        ours, theirs = ctx.Pipe()
        reader = ctx.Process(target=reader_main, name="bench-reader", daemon=True,
                             args=(theirs, endpoints, hosts))
        reader.start()
        workers.append(reader)
        yield sim, conns, ours
    finally:
        for proc in workers:
            proc.join(timeout=10)
            if proc.is_alive():
                proc.kill()
        sim.send_signal(signal.SIGTERM)
        try:
            sim.wait(timeout=10)
        except subprocess.TimeoutExpired:
            sim.kill()
            sim.wait()


def _runner_mark(sim: subprocess.Popen[bytes]) -> dict[str, Any]:
    """The simulator's CPU and the machine's, at one end of the window."""
    return {"wall": time.monotonic(), "sim_cpu_s": process_cpu_s(sim.pid),
            "machine": machine_ticks()}


def _wait(conn: Connection, who: str) -> dict[str, Any]:
    try:
        if not conn.poll(READY_TIMEOUT_S):
            raise BusError(f"{who} did not answer within {READY_TIMEOUT_S:g} s")
        return receive(conn)
    except EOFError:
        raise BusError(f"{who} ended without an answer (its traceback is above)") from None


def _percentiles(values: np.ndarray) -> dict[str, float]:
    if not len(values):
        return {"p50": float("nan"), "p99": float("nan"), "max": float("nan")}
    return {"p50": float(np.percentile(values, 50)), "p99": float(np.percentile(values, 99)),
            "max": float(values.max())}


def summarize(windows: list[dict[str, Any]], reader: dict[str, Any],
              patches: int) -> dict[str, Any]:
    """The figures from the hosts' windows and the reader's columns."""
    cols = {k: np.asarray(v) for k, v in reader["columns"].items()}
    per_host = spread(patches, len(windows))
    expected = got = cycles = host_samples = host_complete = 0
    keep = np.zeros(len(cols["cycle"]), dtype=bool)
    for k, window in enumerate(windows):
        first, last = window["first_cycle"], window["last_cycle"]
        n_cycles = max(0, last - first + 1)
        cycles += n_cycles
        expected += n_cycles * len(per_host[k])
        mine = (cols["host"] == f"host{k}") & (cols["cycle"] >= first) & (cols["cycle"] <= last)
        keep |= mine
        unique = {(int(p), int(c)) for p, c, ok in zip(
            cols["patch"][mine], cols["cycle"][mine], cols["complete"][mine], strict=True) if ok}
        got += len(unique)
        host_samples += window["samples"]
        host_complete += window["complete"]
    sync = cols["sync"][keep]
    latency = 1e3 * (cols["received"][keep] - sync)
    pdo = 1e3 * (cols["published"][keep] - sync)
    added = 1e3 * (cols["received"][keep] - cols["published"][keep])
    samples = sum(w["samples"] for w in windows)
    cpu = sum(w["cpu_s"] for w in windows)
    publish = {k: sum(w["publish_cpu_s"][k] for w in windows)
               for k in windows[0]["publish_cpu_s"]}
    per_sample = 1e6 / max(samples, 1)
    lat, pdo_lat = _percentiles(latency), _percentiles(pdo)
    return {
        "hosts": len(windows), "patches": patches, "cycles": cycles,
        "samples_expected": expected, "samples_received_complete": got,
        "reader_complete_pct": 100.0 * got / max(expected, 1),
        "host_complete_pct": 100.0 * host_complete / max(host_samples, 1),
        "latency_ms": lat, "pdo_latency_ms": pdo_lat,
        "zenoh_added_p99_ms": lat["p99"] - pdo_lat["p99"],
        "publish_to_reader_ms": _percentiles(added),
        "publish_cpu_us_per_sample": per_sample * sum(publish.values()),
        "publish_cpu_us_per_sample_parts": {k: per_sample * v for k, v in publish.items()},
        "host_cpu_us_per_sample": per_sample * cpu,
        "publish_share_pct": 100.0 * sum(publish.values()) / max(cpu, 1e-12),
        "host_cpu_pct": [100.0 * w["cpu_s"] / max(w["seconds"], 1e-9) for w in windows],
        "publisher_dropped": sum(w["dropped"] for w in windows),
        "reader_cpu_pct": 100.0 * reader["cpu_s"] / max(reader["seconds"], 1e-9),
        "reader_cpu_us_per_sample": 1e6 * reader["cpu_s"] / max(int(keep.sum()), 1),
        "reader_samples": int(keep.sum()),
        "reader_received": reader["counters"]["received"],
        "reader_rejected": reader["counters"]["rejected"],
    }
