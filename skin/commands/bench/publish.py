"""``skin bench publish``: hosts publishing on Zenoh and one reader, on loopback
(:mod:`skin.benchmarks.publish`); the command line and the printed figures."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from skin.commands.common import argtypes


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("publish", "skin bench publish (--patches, --seconds "
                                                 "as above; defaults 32 and 10)")
    group.add_argument("--hosts", type=argtypes.count("hosts", 1, 16), default=None, metavar="H",
                       help="host processes, each with its patches on its own "
                            "udp_multicast bus (default 4)")
    group.add_argument("--express", action="store_true",
                       help="force samples with Zenoh's express flag (never batched; "
                            "default: zenoh.express's default, off)")


def run_publish(args: argparse.Namespace,
                write_json: Callable[[str, dict[str, Any]], None]) -> int:
    from canbus.master.zenoh_settings import require_zenoh
    from skin.benchmarks.publish import (
        DEFAULT_HOSTS,
        DEFAULT_PATCHES,
        DEFAULT_SECONDS,
        run_publish_benchmark,
    )
    from skin.errors import ConfigError

    require_zenoh("skin bench publish")
    hosts = args.hosts if args.hosts is not None else DEFAULT_HOSTS
    patches = args.patches if args.patches is not None else DEFAULT_PATCHES
    seconds = args.seconds if args.seconds is not None else \
        (3.0 if args.quick else DEFAULT_SECONDS)
    if not 1 <= hosts <= 16:
        raise ConfigError("--hosts", f"must be in 1..16, got {hosts}")
    if patches < hosts:  # --patches is a node-ID count already (argtypes.patches)
        raise ConfigError("--patches", f"must be in {hosts}..127 (one patch or more per "
                          f"host), got {patches}")
    if not seconds > 0:
        raise ConfigError("--seconds", f"must be > 0, got {seconds}")
    result = run_publish_benchmark(hosts, patches, seconds, express=args.express)
    print_publish(result)
    if args.json:
        write_json(args.json, result)
    return 0


def print_publish(r: dict[str, Any]) -> None:
    lat, pdo = r["latency_ms"], r["pdo_latency_ms"]
    load = r["load_average"]
    print(f"{r['hosts']} hosts, {r['patches']} patches (3-axis, 100 Hz), {r['cycles']} SYNC "
          f"cycles in {r['seconds']:g} s; Zenoh on loopback, express "
          f"{'on' if r['express'] else 'off'}")
    if r["fits_machine"]:
        print(f"fits this machine: {r['why']}")
    else:
        print(f"does not fit this machine: {r['why']}")
    print(f"reader got {r['reader_complete_pct']:.3f} % of {r['samples_expected']:,} samples "
          f"complete (the hosts made {r['host_complete_pct']:.3f} % complete)"
          + ("" if r["fits_machine"] else
             ": what this machine carried, not what Zenoh lost"))
    print(f"SYNC -> reader    p50 {lat['p50']:.2f} ms, p99 {lat['p99']:.2f} ms, "
          f"max {lat['max']:.2f} ms")
    print(f"SYNC -> force PDO p50 {pdo['p50']:.2f} ms, p99 {pdo['p99']:.2f} ms, "
          f"max {pdo['max']:.2f} ms; Zenoh adds {r['zenoh_added_p99_ms']:.2f} ms to the p99")
    parts = ", ".join(f"{k} {v:.1f}" for k, v in r["publish_cpu_us_per_sample_parts"].items())
    print(f"host CPU per sample {r['host_cpu_us_per_sample']:.1f} us, of which publishing "
          f"{r['publish_cpu_us_per_sample']:.1f} us ({r['publish_share_pct']:.1f} %: {parts})")
    print(f"reader CPU {r['reader_cpu_pct']:.1f} % of a core, "
          f"{r['reader_cpu_us_per_sample']:.1f} us per sample")
    print_cpu(r["cpu"], r["rate_hz"])
    codec = r["codec"]
    print("encodings: " + "; ".join(
        f"{k} {v['bytes']:.0f} B, encode {v['encode_us']:.1f} us, decode {v['decode_us']:.1f} us"
        for k, v in codec.items()))
    print(f"load average {load['before'][0]:.2f} before, {load['after'][0]:.2f} after, on "
          f"{r['cpu_count']} CPUs")


def _figure(value: float | None, spec: str = ".0f") -> str:
    return "-" if value is None else format(value, spec)


def print_cpu(cpu: dict[str, Any], rate_hz: float) -> None:
    """Where the window's CPU went, each process's cost per unit of work, and its need."""
    need = cpu["need_pct"]
    print(f"CPU, % of a core: hosts {'+'.join(_figure(v) for v in cpu['hosts_pct'])}, "
          f"simulator {cpu['simulator_pct']:.0f}, reader {cpu['reader_pct']:.0f}: "
          f"{cpu['total_pct']:.0f} of the machine's {cpu['capacity_pct']:.0f}; the machine "
          f"was busy {cpu['machine_busy_pct']:.0f} ({cpu['other_pct']:.0f} beyond these)")
    print(f"per unit of work: a host "
          f"{'/'.join(_figure(v, '.1f') for v in cpu['host_us_per_frame'])} us per bus frame "
          f"({'/'.join(_figure(v, ',.0f') for v in cpu['host_frames_per_s'])} frames/s), "
          f"the simulator {_figure(cpu['simulator_us_per_frame'], '.1f')} us per bus frame, "
          f"the reader {_figure(cpu['reader_us_per_sample'], '.1f')} us per sample")
    print(f"needed at {rate_hz:g} Hz, % of a core: hosts "
          f"{'+'.join(_figure(v) for v in need['hosts'])}, simulator "
          f"{_figure(need['simulator'])}, reader {_figure(need['reader'])}: "
          f"{need['total']:.0f} of {cpu['capacity_pct']:.0f}")
