"""The deployment's shape: `skin sim run` (8 patches, 3-axis, 100 Hz) and the host in two
processes on udp_multicast for 10 s; prints the share of complete samples, per run.

    python -m tests.support.two_process [--runs 3] [--seconds 10] [--pin]

The host is `skin run examples/host8.toml` as it is (it drops the echoes of its own frames in
the kernel: docs/host.md). ``--pin`` puts the patches on CPU 0 and the host on CPU 1
(``--cpu``). Each run has its own multicast group and port.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "examples" / "host8.toml"


def one_run(k: int, seconds: float, pin: bool) -> dict[str, float]:
    group, port = f"239.74.{os.getpid() % 250}.{200 + k}", 32000 + (os.getpid() % 500) * 8 + k
    bus = ["-i", "udp_multicast", "-c", group, "--bus-kwargs", f"port={port}"]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "host.json"
        patches = subprocess.Popen(
            [sys.executable, "-m", "skin.cli", "sim", "run", "indenter", "--patches", "8",
             *bus, "--seconds", str(seconds + 6), "--cpu", "0" if pin else "all"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(2.5)
        load = os.getloadavg()[0]
        cmd = [sys.executable, "-m", "skin.cli", "run", str(CONFIG), *bus, "--seconds",
               str(seconds), "--json", str(out), "--cpu", "1" if pin else "all"]
        subprocess.run(cmd, capture_output=True, text=True, check=True, timeout=seconds + 60)
        served, _ = patches.communicate(timeout=30)
        stats = json.loads(out.read_text())["stats"]
    complete = stats["complete_samples"] / max(stats["samples"], 1)
    return {"complete_pct": 100 * complete, "samples": stats["samples"],
            "late_frames": stats["late_frames"], "unknown_frames": stats["unknown_frames"],
            "sync_overruns": stats["sync_overruns"], "load_average": load,
            "patches": served.strip().splitlines()[-1]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--pin", action="store_true")
    args = parser.parse_args()
    for k in range(args.runs):
        result = one_run(k, args.seconds, args.pin)
        print(f"run {k + 1}: {result['complete_pct']:.2f} % of {result['samples']} samples "
              f"complete; late frames {result['late_frames']}, unknown {result['unknown_frames']}"
              f", SYNC overruns {result['sync_overruns']}; load {result['load_average']:.1f}; "
              f"patches: {result['patches']}", flush=True)


if __name__ == "__main__":
    main()
