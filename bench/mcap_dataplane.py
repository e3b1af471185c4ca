"""Benchmark: the host's data plane with an MCAP recorder beside it, against without.

    python -m bench.mcap_dataplane [--patches 16] [--cycles 300] [--repeats 5]

The whole threaded path of :func:`bench.dataplane.pipeline_rate` (virtual bus, notifier,
data plane and its publishing thread, force nodes, contact summaries), alone and with a
:class:`~canbus.tools.recorder.Recorder` as ``skin run --record`` runs it (the frames from
a bus of its own, every sample from the publisher), writing .mcap or .log; interleaved
runs, the best of each. Prints one JSON object: frames in per second of each and the
ratio to the run without.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from bench.dataplane import build_stream, contact_judge, pipeline_rate
from canbus.tools.recorder import Recorder
from decoder.registry import create_decoder


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--patches", type=int, default=16)
    parser.add_argument("--cycles", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    stream = build_stream(args.patches, args.cycles, "xyz")
    decoder = create_decoder("analytic")
    best: dict[str, float] = {"none": 0.0, ".mcap": 0.0, ".log": 0.0}
    written: dict[str, int] = {}
    with tempfile.TemporaryDirectory() as folder:
        for _ in range(args.repeats):
            for kind in best:
                recorder = None if kind == "none" else Recorder(Path(folder) / f"run{kind}")
                rate = pipeline_rate(stream, decoder, contact_judge, recorder=recorder)
                best[kind] = max(best[kind], rate["frames_per_s"])
                if recorder is not None:
                    written[kind] = recorder.written
    print(json.dumps({
        "patches": args.patches, "cycles": args.cycles, "repeats": args.repeats,
        "frames_in": stream.frame_count,
        "frames_per_s": {k: round(v) for k, v in best.items()},
        "ratio_to_none": {k: round(v / best["none"], 3) for k, v in best.items()},
        "frames_recorded": written}, indent=2))


if __name__ == "__main__":
    main()
