"""The calibration loop end to end, as a user runs it, in separate processes on udp_multicast.

``python -m tests.support.rigs.calibration [--fd] [--samples N] [--folder DIR]`` prints the
figures of docs/calibrate.md; ``tests/skin/test_calibrate_e2e.py`` asserts them.

1. ``skin run host.toml`` (the host; classic CAN, or CAN FD with ``--fd``) and, for each of two
   runs, ``skin sniff --record runN.log`` and ``skin sim run calibration --truth truthN.csv
   --seed N``, the simulator stopped by SIGTERM (its truth must survive it);
2. ``skin dataset from-recording run1.log --reference truth1.csv -o d1.npz`` (and d2);
3. ``skin calibrate d1.npz -o m.msgpack --config-snippet patch.toml``;
4. ``skin decode run2.log`` with a listen-only config holding that snippet (the listen-only
   host, offline), and with the default analytic decoder; both joined to truth2 by SYNC
   counter; the oracle (the scene's true crosstalk and rest) on d2.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tests.support.rigs.children import Child, spawn
from tests.support.rigs.ports import udp_bus
from tests.support.rigs.waiting import wait_until

ROOT = Path(__file__).resolve().parents[3]
SCENE = "calibration"
HOST = """[host]
sync_period_ms = 10.0
heartbeat_ms = 100
scan_ms = 100
{listen}
[bus]
fd = {fd}
"""


def _skin(*args: str) -> list[str]:
    return [sys.executable, "-m", "skin.cli", *args]


def record(folder: Path, *, classic: bool, samples: int, group: str, port: int,
           timeout: float = 180.0) -> None:
    """Two recordings with a host running: runN.log, truthN.csv (N = 1, 2), each until the
    simulator has answered ``samples`` SYNCs in time (its truth holds them): a busy machine
    takes longer, never gives fewer samples. Each process's output: NAME.out."""
    bus = ["-i", "udp_multicast", "-c", group, "--bus-kwargs", f"port={port}"]
    (folder / "host.toml").write_text(HOST.format(listen="", fd=str(not classic).lower())
                                      + "\n[[patches]]\nnode_id = 1\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    started: dict[str, Child] = {}

    def start(name: str, *args: str) -> Child:
        started[name] = spawn(_skin(*args), cwd=folder, env=env)
        return started[name]

    try:
        host = start("host", "run", "host.toml", *bus)
        host.wait_for("Ctrl-C stops", timeout=60)
        for run in (1, 2):
            _one_recording(start, run, bus, folder / f"truth{run}.csv", samples, timeout)
        if host.stop(signal.SIGINT) != 0:
            raise RuntimeError(host.output())
    finally:
        for name, child in started.items():
            if child.running():
                child.kill()
            (folder / f"{name}.out").write_text(child.output())


def _one_recording(start: Callable[..., Child], run: int, bus: list[str], truth: Path,
                   samples: int, timeout: float) -> None:
    """runN.log by ``skin sniff`` while ``skin sim run`` answers ``samples`` SYNCs."""
    sniff = start(f"sniff{run}", "sniff", "--record", f"run{run}.log", "--view", "none", *bus)
    sniff.wait_for("Ctrl-C stops", timeout=60)  # --view none: on stdout
    sim = start(f"sim{run}", "sim", "run", SCENE, "--truth", truth.name, "--seed", str(run),
                *bus)
    wait_until(lambda: _truth_samples(truth) >= samples or not sim.running(),
               what=f"{samples} answered SYNCs in {truth}", timeout=timeout)
    if sim.stop(signal.SIGTERM) != 0:  # as a service manager stops it
        raise RuntimeError(sim.output())
    if sniff.stop(signal.SIGINT) != 0:
        raise RuntimeError(sniff.output())


def _truth_samples(path: Path) -> int:
    """Samples in a truth file being written (nine rows each, flushed whole)."""
    if not path.exists():
        return 0
    with path.open("rb") as handle:
        return max(0, sum(1 for _ in handle) - 1) // 9


@dataclass
class Figures:
    """Floored AveRelErr % on the second recording, and what each step reported."""

    calibrated_pct: float
    analytic_pct: float
    oracle_pct: float
    calibrated_refused_pct: float
    compared_samples: int
    report: dict[str, Any]
    dataset1: dict[str, Any]
    dataset2: dict[str, Any]


def decoded_error(forces: Path, truth: Path) -> tuple[float, float, int]:
    """(floored %, refused %, samples) of a decode's complete samples against the truth."""
    from canbus.tools.join import Series, join
    from decoder.metrics import evaluate
    from skin.reference import read_reference

    ref = read_reference(truth)
    with np.load(forces) as z:
        ok = z["complete"] & (z["patch"] == 1)
        recorded = Series(z["time_s"][ok], z["sync_counter"][ok].astype(np.int64),
                          np.full(int(ok.sum()), np.nan))
        found = join(recorded, Series(ref.time_s, ref.sync, np.zeros(len(ref.sync))),
                     by="sync", period_s=0.01, clock_offset_s=0.0)
        force, valid = z["force_N"][ok][found.recorded], z["valid"][ok][found.recorded]
    e = evaluate(ref.force_N[found.reference], force, valid, mode="xyz")
    return e.ave_rel_err_floored_pct, 100.0 * (1.0 - valid.mean()), int(found.recorded.size)


def oracle_error(dataset: Path) -> float:
    from decoder.metrics import evaluate
    from decoder.oracle import oracle_decode
    from sim import load_scene
    from sim.pipeline import Pipeline
    from skin.constants import DEFAULT_CONSTANTS
    from skin.dataset import read_dataset

    scene, ds = load_scene(SCENE), read_dataset(dataset)
    rest = Pipeline(scene, DEFAULT_CONSTANTS, 0, 1).baseline()  # the scene's true rest
    out = oracle_decode(ds.resistance_ohm, scene.crosstalk_matrix(), r0_ohm=rest)
    return evaluate(ds.force_N, out.force_N, out.valid, mode="xyz").ave_rel_err_floored_pct


def loop(folder: Path, *, classic: bool, decoders: list[str] | None = None) -> Figures:
    """Steps 2 to 4 on the recordings in ``folder``, through the command line (in process)."""
    from skin.cli import main

    def skin(*args: str) -> None:
        code = main([*args])
        if code != 0:
            raise RuntimeError(f"skin {' '.join(args)} exited {code}")

    os.chdir(folder)
    for run in (1, 2):
        skin("dataset", "from-recording", f"run{run}.log", "--reference", f"truth{run}.csv",
             "-o", f"d{run}.npz", "--json", f"d{run}.json")
    skin("calibrate", "d1.npz", "-o", "m.msgpack", "--config-snippet", "patch.toml",
         "--report", "report.json", "--json", "calibrate.json",
         *(["--decoders", *decoders] if decoders else []))
    listen = HOST.format(listen="listen_only = true", fd=str(not classic).lower())
    Path("listen.toml").write_text(listen + "\n" + Path("patch.toml").read_text())
    Path("analytic.toml").write_text(listen + "\n[[patches]]\nnode_id = 1\n")
    skin("decode", "run2.log", "--config", "listen.toml", "-o", "calibrated.npz")
    skin("decode", "run2.log", "--config", "analytic.toml", "-o", "analytic.npz")
    calibrated, refused, compared = decoded_error(Path("calibrated.npz"), Path("truth2.csv"))
    analytic, _, _ = decoded_error(Path("analytic.npz"), Path("truth2.csv"))
    return Figures(calibrated, analytic, oracle_error(Path("d2.npz")), refused, compared,
                   json.loads(Path("report.json").read_text()),
                   json.loads(Path("d1.json").read_text()),
                   json.loads(Path("d2.json").read_text()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fd", action="store_true", help="CAN FD, not classic CAN")
    parser.add_argument("--samples", type=int, default=400,
                        help="answered SYNCs per recording (100 a second)")
    parser.add_argument("--folder", help="where to work (default: a temporary folder)")
    args = parser.parse_args()
    folder = Path(args.folder or tempfile.mkdtemp(prefix="calibration-"))
    folder.mkdir(parents=True, exist_ok=True)
    group, port = udp_bus()
    record(folder, classic=not args.fd, samples=args.samples, group=group, port=port)
    f = loop(folder, classic=not args.fd)
    print(f"\nfolder {folder}")
    for run, d in ((1, f.dataset1), (2, f.dataset2)):
        p = d["patches"]["1"]
        print(f"run {run}: {d['samples']} samples written; recording "
              f"{p['recording']}; left out {p['joined_but_incomplete']} incomplete, "
              f"{p['joined_but_unanswered']} unanswered; unjoined {p['unjoined_reference']} "
              f"reference, {p['unjoined_recording']} recorded")
    print(f"chose {f.report['decoder']} (hidden {f.report['hidden']}), held-out floored "
          f"{f.report['heldout_floored_pct']:.3f} %")
    print(f"second recording, {f.compared_samples} samples: calibrated {f.calibrated_pct:.3f} % "
          f"(refused {f.calibrated_refused_pct:.2f} %), oracle {f.oracle_pct:.3f} %, "
          f"uncalibrated analytic {f.analytic_pct:.1f} %: calibrated/oracle "
          f"{f.calibrated_pct / f.oracle_pct:.3f}, analytic/calibrated "
          f"{f.analytic_pct / f.calibrated_pct:.0f}x")


if __name__ == "__main__":
    main()
