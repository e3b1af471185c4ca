"""Benchmark: the host's data plane with an MCAP recorder beside it, against without.

    python -m tests.support.mcap_dataplane [--patches 16] [--cycles 300] [--repeats 3] [--pace FPS]

The whole threaded path of :func:`skin.benchmarks.pipeline.pipeline_rate` (a bus, notifier, data
plane and its publishing thread, force nodes, contact summaries) as fast as it goes, on
udp_multicast over loopback (a group and port of ``tests.support.rigs.ports``), alone and with
the recorder ``skin run --record run.mcap`` runs: ``process``, the recording process
(:mod:`skin.commands.common.recordproc`: its own socket, the samples over a pipe), as on any bus
another process hears; ``thread``, a :class:`~canbus.tools.recorder.Recorder` thread and
a second socket in the host's process, as on an in-process bus. ``--pace 20000``: the
cycles are sent at that many frames/s (a bus's rate) instead of as fast as the data plane
takes them. Every socket asks for the 4 MiB receive buffer the commands ask for.
Interleaved runs, the best of each. Prints one JSON object: frames in per second, the
ratio to the run without, and
the frames and samples each recording holds.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path
from typing import Any

from canbus.master.busconfig import BusConfig
from canbus.offline.mcap import read_forces
from canbus.rxbuffer import DEFAULT_RCVBUF
from canbus.tools.recorder import Recorder
from canbus.tools.recording import Recording
from decoder.registry import create_decoder
from skin.benchmarks.dataplane_rigs import build_stream, contact_judge
from skin.benchmarks.pipeline import pipeline_rate
from skin.commands.common.recordproc import RecordingProcess
from tests.support.rigs.ports import udp_bus

KINDS = ("none", "process", "thread")


def _recorder(kind: str, path: Path, group: str, port: int) -> Any:
    if kind == "thread":
        return Recorder(path)
    bus = BusConfig(interface="udp_multicast", channel=group, options={"port": port})
    return RecordingProcess(str(path), [bus], channel=None, placements=None,
                            rcvbuf=DEFAULT_RCVBUF)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--patches", type=int, default=16)
    parser.add_argument("--cycles", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--pace", type=float, default=None, metavar="FPS")
    args = parser.parse_args()
    stream = build_stream(args.patches, args.cycles, "xyz")
    decoder = create_decoder("analytic")
    group, port = udp_bus()
    bus = {"interface": "udp_multicast", "channel": group, "port": port}
    best = dict.fromkeys(KINDS, 0.0)
    held: dict[str, dict[str, int]] = {}
    with tempfile.TemporaryDirectory() as folder:
        for _ in range(args.repeats):
            for kind in KINDS:
                path = Path(folder) / f"{kind}.mcap"
                recorder = None if kind == "none" else _recorder(kind, path, group, port)
                try:
                    rate = pipeline_rate(stream, decoder, contact_judge, bus=bus,
                                         recorder=recorder, pace=args.pace)
                finally:
                    if isinstance(recorder, RecordingProcess):
                        recorder.stop()
                best[kind] = max(best[kind], rate["frames_per_s"])
                if recorder is not None:
                    with Recording(path) as frames:
                        held[kind] = {"frames": sum(1 for _ in frames),
                                      "samples": sum(1 for _ in read_forces(str(path)))}
    print(json.dumps({
        "patches": args.patches, "cycles": args.cycles, "repeats": args.repeats,
        "pace": args.pace,
        "frames_in": stream.frame_count, "samples": args.patches * args.cycles,
        "frames_per_s": {k: round(v) for k, v in best.items()},
        "ratio_to_none": {k: round(v / best["none"], 3) for k, v in best.items()},
        "last_recording": held}, indent=2))


if __name__ == "__main__":
    main()
