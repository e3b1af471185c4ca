"""``skin decode REC --config host.toml -o forces.csv|.npz``: a recording's forces, offline.

The recording (.log, .asc, .blf, .pcap, .pcapng) goes through the listen-only host on its
own clock (:mod:`canbus.master.offline`): the forces are what a listen-only host publishes
for it, the same every time, with no bus; what it says of each patch (samples, stretches
without an answer, invalid taxels) is in seconds of the recording
(:mod:`skin.commands.decode_report`), never a live host's "lost" or "in the last N s".
Output, written atomically:

- ``.csv``: one row per taxel of every sample: ``cycle, sync_counter, time_s, patch,
  force_node, taxel, fx_N, fy_N, fz_N, valid, reason, complete`` (``reason`` by name);
- ``.npz``: arrays ``cycle, sync_counter, time_s, patch, force_node, complete`` (samples,)
  and ``force_N`` (samples, 9, 3), ``valid``, ``reason`` (samples, 9), and ``meta`` (JSON).
"""

from __future__ import annotations

import argparse
import io
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from canbus.master.dataplane import ForceFrame

FORMATS = (".csv", ".npz")


def _decode(args: argparse.Namespace) -> int:
    from canbus.master.hostconfig import load_host_config
    from canbus.master.offline import decode_recording
    from canbus.tools.replay import recording_reader
    from skin.atomic import atomic_write
    from skin.commands.decode_report import first_frame_time, lines, quiet_host, report, to_json
    from skin.errors import ConfigError

    recording_reader(args.recording, field="REC")
    suffix = Path(args.output).suffix.lower()
    if suffix not in FORMATS:
        raise ConfigError("-o", f"unknown output format {suffix or '(no suffix)'!r}; use "
                          f"{' or '.join(FORMATS)}")
    config = load_host_config(args.config)
    with quiet_host():
        frames = decode_recording(args.recording, config)
    data = _csv(frames) if suffix == ".csv" else _npz(frames, args, config.source)
    with atomic_write(args.output) as handle:
        handle.write(data)
    complete = sum(f.complete for f in frames)
    patches = sorted({f.patch for f in frames})
    print(f"decoded {len(frames)} samples ({complete} complete) of patches "
          f"{', '.join(map(str, patches)) or 'none'} from {args.recording} -> {args.output}")
    reports = report(frames, first_frame_time(args.recording))
    for line in lines(reports):
        print(line)
    if args.json:
        summary = {"recording": args.recording, "output": args.output, "samples": len(frames),
                   "complete_samples": complete,
                   "patches": {str(p): sum(f.patch == p for f in frames) for p in patches},
                   "by_patch": to_json(reports)}
        with atomic_write(args.json) as handle:
            handle.write(json.dumps(summary, indent=2).encode() + b"\n")
    return 0


def _csv(frames: list[ForceFrame]) -> bytes:
    from decoder.reasons import reason_name

    out = io.StringIO()
    out.write("cycle,sync_counter,time_s,patch,force_node,taxel,fx_N,fy_N,fz_N,valid,reason,"
              "complete\n")
    for f in frames:
        for taxel in range(len(f.valid)):
            fx, fy, fz = (repr(float(v)) for v in f.force_N[taxel])
            out.write(f"{f.cycle},{f.sync_counter},{f.timestamp!r},{f.patch},{f.force_node},"
                      f"{taxel},{fx},{fy},{fz},{int(f.valid[taxel])},"
                      f"{reason_name(int(f.reason[taxel]))},{int(f.complete)}\n")
    return out.getvalue().encode()


def _npz(frames: list[ForceFrame], args: argparse.Namespace, config: str) -> bytes:
    import numpy as np

    arrays: dict[str, Any] = {
        "cycle": np.array([f.cycle for f in frames], dtype=np.int64),
        "sync_counter": np.array([f.sync_counter for f in frames], dtype=np.uint8),
        "time_s": np.array([f.timestamp for f in frames], dtype=np.float64),
        "patch": np.array([f.patch for f in frames], dtype=np.uint8),
        "force_node": np.array([f.force_node for f in frames], dtype=np.uint8),
        "complete": np.array([f.complete for f in frames], dtype=bool),
        "force_N": np.array([f.force_N for f in frames], dtype=np.float64).reshape(-1, 9, 3),
        "valid": np.array([f.valid for f in frames], dtype=bool).reshape(-1, 9),
        "reason": np.array([f.reason for f in frames], dtype=np.uint8).reshape(-1, 9),
        "meta": np.array(json.dumps({"recording": args.recording, "config": config})),
    }
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def add_subparser(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "decode", help="a recording's forces, offline (as a listen-only host publishes them)",
        description="Decode the patches' PDOs in a recording (.log, .asc, .blf, .pcap, "
                    ".pcapng) into forces with the host config's decoders, on the "
                    "recording's own clock: what a listen-only host publishes for it, "
                    "the same every time, without a bus.")
    parser.add_argument("recording", metavar="REC", help="the recording")
    parser.add_argument("--config", required=True, metavar="CONFIG",
                        help="the host config (patches, modes, decoders, SYNC window)")
    parser.add_argument("-o", "--output", required=True, metavar="F.csv|F.npz")
    parser.add_argument("--json", metavar="FILE", help="write a summary as JSON")
    parser.set_defaults(func=_decode)
