"""``skin replay FILE``: a recording (.log, .asc, .blf, .pcap, .mcap) back onto a bus.

The bus stamps what it sends, in both timings (the recorded timestamps are not carried:
a consumer sees the bus's time, as it would live). To decode the forces of a recording,
replay it to ``skin run CONFIG --listen-only`` on the same bus.

Ctrl-C, SIGTERM and SIGHUP stop a replay normally: the summary of what was sent,
``--json``, exit status 0. ``--partial`` replays a recording whose writer was killed up to
its last whole frame.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from skin.commands.common import argtypes


def _replay(args: argparse.Namespace) -> int:
    from canbus.tools.recording import Recording
    from canbus.tools.replay import Replayer
    from skin.atomic import atomic_write
    from skin.commands.common.busopen import open_command_bus
    from skin.commands.common.signals import until_stopped
    from skin.errors import ConfigError, RecordingError

    if args.loop is not None and args.loop < 0:
        raise ConfigError("--loop", f"must be 0 (for ever) or a positive count, got {args.loop}")
    if not args.skip > 0:
        raise ConfigError("--skip", f"must be positive, got {args.skip}")
    if args.rate is not None and not args.rate > 0:
        raise ConfigError("--rate", f"must be a positive number of frames/s, got {args.rate}")
    with Recording(args.file):  # suffix and file header checked before the bus is opened
        pass
    bus, described = open_command_bus(args, command="skin replay", sends=True)
    passes = 1 if args.loop is None else args.loop
    rate = args.rate if args.rate is not None else DEFAULT_RATES.get(args.interface)

    def progress(done: int, frames: int) -> None:
        if passes != 1:
            print(f"pass {done}: {frames:,} frames", file=sys.stderr, flush=True)

    with bus:
        replayer = Replayer(bus, args.file, realtime=not args.fast, passes=passes,
                            skip_s=args.skip, error_frames=args.error_frames,
                            rate_fps=rate if args.fast else None, partial=args.partial)
        try:
            with until_stopped() as stopped:
                replayer.run(on_pass=progress)
        except RecordingError as err:
            raise RecordingError(err.source, err.frame, f"{err.problem} (sent "
                                 f"{replayer.sent:,} frames before it)") from err
    result = replayer.result()  # what was sent, however it ended
    pacing = ", as fast as possible" if rate is None else f", paced to {rate:,.0f} frames/s"
    achieved = result.frames_sent / result.seconds if result.seconds > 0 else 0.0
    print(f"sent {result.frames_sent:,} frames in {result.seconds:.2f} s ({achieved:,.0f} "
          "frames/s, "
          f"{result.passes} pass{'es' if result.passes != 1 else ''}"
          f"{', original timing' if not args.fast else pacing})"
          + (f"; skipped {result.error_frames_skipped:,} error frames"
             if result.error_frames_skipped else "")
          + (f"; stopped by {stopped.signal}" if stopped.signal else ""))
    if args.json:
        record = {"file": args.file, "bus": described, "frames_sent": result.frames_sent,
                  "error_frames_skipped": result.error_frames_skipped,
                  "passes": result.passes, "seconds": result.seconds,
                  "timing": "fast" if args.fast else "original",
                  "rate_fps": rate if args.fast else None,
                  "stopped_by": stopped.signal,
                  "cut": None if replayer.cut is None else str(replayer.cut)}
        with atomic_write(args.json) as handle:
            handle.write(json.dumps(record, indent=2).encode() + b"\n")
    return 0


DEFAULT_RATES = {"udp_multicast": 5_000.0}
"""--fast's pace where nothing else holds a sender back. udp_multicast has no flow control:
a listen-only host in another process loses frames beyond about 8,000 frames/s on a
2-core machine (docs/sniffer.md); 5,000 is what a 1 Mbit/s CAN bus carries at about 60 %
load."""


def _defaults_text() -> str:
    return ", ".join(f"{rate:,.0f} on {name}" for name, rate in DEFAULT_RATES.items())


def add_subparser(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "replay", help="a recording back onto a bus",
        description="Send a recording (.log, .asc, .blf, .pcap, .mcap) onto a bus with its "
                    "original timing or as fast as possible. A truncated or corrupt file "
                    "stops at its first bad frame, which the error names; nothing past it is sent. "
                    "Receivers see the bus's own timestamps, as live; `skin run CONFIG "
                    "--listen-only` on the same bus decodes the forces.")
    parser.add_argument("file", metavar="FILE", help="the recording")
    parser.add_argument("--fast", action="store_true",
                        help="as fast as the bus takes frames, or --rate (default: original "
                             "timing)")
    parser.add_argument("--rate",
                        type=argtypes.number("rate", above=0.0, high=10**7, unit="frames/s"),
                        default=None, metavar="FPS",
                        help="with --fast: at most FPS frames/s (default: unpaced, except "
                             f"{_defaults_text()})")
    parser.add_argument("--loop", type=argtypes.count("passes", 0, 10**9), nargs="?", const=0,
                        default=None, metavar="N",
                        help="play N times in all; without N, until Ctrl-C")
    parser.add_argument("--skip", type=argtypes.seconds, default=60.0, metavar="S",
                        help="cut recorded pauses longer than S seconds to S (default 60)")
    parser.add_argument("--partial", action="store_true",
                        help="a recording whose writer was killed: a bad frame at the very "
                             "end of the file (a cut line or record, an .asc without its "
                             "footer) ends the replay with a warning instead of an error")
    parser.add_argument("--error-frames", action="store_true",
                        help="also send error frames (most interfaces cannot)")
    parser.add_argument("--json", type=argtypes.output_file, metavar="FILE",
                        help="write the figures as JSON")
    argtypes.add_bus_arguments(parser)
    parser.set_defaults(func=_replay, runs_until_stopped=True)
