"""``skin view``: the skin as every patch's 3x3 taxels at its place, live or from a recording.

Sources: a bus (the force nodes' PDOs, read as any CANopen master reads them; with
``--decode --config host.toml`` the patches' PDOs decoded in this process by a listen-only
host), or a recording FILE played with its own timing (``--fast``: as fast as it goes).
Outputs: a rich live view on a terminal (redraws are dropped, never frames), one plain
text frame (``--snapshot``; also what a run prints when stdout is not a terminal), a
PNG of one moment, a GIF or MP4 of a span, a trace of one taxel; a summary, and its JSON.
Rendering: :mod:`skin.commands.view.term` (terminal), :mod:`skin.commands.view.plot`
(pictures); the sources: :mod:`skin.commands.view.sources`.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from skin.commands.common import argtypes
from skin.commands.view.layout import Layout, layout_from_positions, parse_layout
from skin.commands.view.recorded import DEFAULT_FPS, animation, moment, trace
from skin.commands.view.report import report, view_title
from skin.commands.view.term import DEFAULT_SCALE_N, SkinView

if TYPE_CHECKING:
    from canbus.master.hostconfig import HostConfig
    from skin.commands.view.sources import BusDecode, BusForces, Playback, RecordingTimes

_TICK_S = 0.05


def _positive(args: argparse.Namespace, *names: str) -> None:
    from skin.errors import ConfigError

    for name in names:
        value = getattr(args, name)
        if value is not None and not (math.isfinite(value) and value > 0):
            raise ConfigError(f"--{name.replace('_', '-')}", f"must be positive, got {value}")


def _check(args: argparse.Namespace) -> None:
    """Refuse what does not go together, before any file or bus is opened."""
    from skin.errors import ConfigError

    _positive(args, "scale", "seconds", "refresh", "fps")
    from skin.commands.view.zenoh import check_zenoh_arguments

    check_zenoh_arguments(args)
    pictures = [f for f in ("png", "gif", "mp4", "plot") if getattr(args, f)]
    if len(pictures) + args.snapshot > 1:
        chosen = ", ".join(f"--{f}" for f in pictures + ["snapshot"] * args.snapshot)
        raise ConfigError(chosen.split(", ")[1], f"one output at a time, got {chosen}")
    if pictures and not args.file:
        raise ConfigError(f"--{pictures[0]}", "draws a recording: give FILE")
    for flag in ("at", "fast"):
        if getattr(args, flag) not in (None, False) and not args.file:
            raise ConfigError(f"--{flag}", "applies to a recording FILE")
    if args.at is not None and not (args.png or args.snapshot):
        raise ConfigError("--at", "goes with --png or --snapshot")
    span = [f for f in ("start", "end", "fps") if getattr(args, f) is not None]
    if span and not (args.gif or args.mp4 or args.plot):
        flag = {"start": "--from", "end": "--to", "fps": "--fps"}[span[0]]
        raise ConfigError(flag, "goes with --gif, --mp4 or --plot")
    for name, value in (("--at", args.at), ("--from", args.start), ("--to", args.end)):
        if value is not None and not (math.isfinite(value) and value >= 0):
            raise ConfigError(name, f"must be a time >= 0 s from the recording's start, got "
                              f"{value}")
    if args.start is not None and args.end is not None and args.end <= args.start:
        raise ConfigError("--to", f"must be after --from ({args.start:g} s), got {args.end:g}")
    if args.plot and (args.patch is None or args.taxel is None):
        raise ConfigError("--plot", "needs --patch N and --taxel K")
    if (args.patch is not None or args.taxel is not None) and not args.plot:
        raise ConfigError("--patch" if args.patch is not None else "--taxel", "goes with --plot")
    if args.raw and not args.plot:
        raise ConfigError("--raw", "goes with --plot")
    if args.decode and not args.config:
        raise ConfigError("--decode", "needs --config host.toml (the patches to decode)")
    if args.ask_by_sdo and (args.file or args.decode or args.zenoh is not None):
        raise ConfigError("--ask-by-sdo", "asks the force nodes on a live bus: not with a "
                          "recording FILE, --decode or --zenoh")
    if args.scene and args.config:
        raise ConfigError("--scene", "give the layout by --scene or by --config, not both")
    if args.mp4 or args.gif:
        from skin.commands.view.plot import check_animation_writer

        check_animation_writer(Path(args.mp4 or args.gif).suffix.lower())
    elif args.png or args.plot:
        from skin.commands.view.plot import pyplot

        pyplot("--png" if args.png else "--plot")
    for flag in ("png", "gif", "mp4", "plot"):
        path = getattr(args, flag)
        expected = ".png" if flag == "plot" else f".{flag}"
        if path and Path(path).suffix.lower() != expected:
            raise ConfigError(f"--{flag}", f"the file must end in {expected}, got {path!r}")


def _layout(args: argparse.Namespace, config: HostConfig | None) -> Layout:
    if args.layout:
        return parse_layout(args.layout)
    if config is not None:
        pitch = next((p.constants.taxel_pitch_m for p in config.patches
                      if p.constants is not None), None)
        positions = {p.node_id: p.position_m for p in config.patches}
        return layout_from_positions(positions, args.config, pitch or Layout().pitch_m)
    if args.scene:
        from sim import load_scene

        scene = load_scene(args.scene)
        places = {p.node_id: p.position_m for p in scene.patches}
        if len(set(places.values())) < len(places):  # unplaced patches: a row
            return Layout.row(places)
        return layout_from_positions(dict(places), f"scene {scene.name}")
    return Layout()


def _view(args: argparse.Namespace) -> int:
    if args.file is None and args.layout:  # `--layout 1=0,0 2=0.05,0 run.log`: the file
        files = [t for t in args.layout if "=" not in t]
        if len(files) == 1:
            args.file = files[0]
            args.layout = [t for t in args.layout if "=" in t]
    _check(args)
    config = None
    if args.config:
        from canbus.master.hostconfig import load_host_config

        config = load_host_config(args.config)
    layout = _layout(args, config)
    if args.zenoh is not None:
        from skin.commands.view.zenoh import run_zenoh

        return run_zenoh(args, layout, _live)
    if args.file:
        from skin.commands.view.sources import recording_times

        times = recording_times(args.file)  # the file is checked before anything else
        if args.plot:
            return trace(args, config, times)
        if args.png or args.snapshot:
            return moment(args, config, layout, times)
        if args.gif or args.mp4:
            return animation(args, config, layout, times)
        return _play(args, config, layout, times)
    return _bus(args, config, layout)


# -- live ----------------------------------------------------------------------------------


def _bus(args: argparse.Namespace, config: HostConfig | None, layout: Layout) -> int:
    from skin.commands.common.busopen import open_command_bus
    from skin.commands.common.tool_config import asking
    from skin.commands.view.live import SNAPSHOT_SECONDS
    from skin.commands.view.sources import BusDecode, BusForces, force_specs

    seconds = args.seconds
    if seconds is None and args.snapshot:
        seconds = SNAPSHOT_SECONDS
    # opened again when it keeps failing (canbus.busio); the first open's failure is
    # BusError "cannot open the bus IFACE:CHANNEL: ..." in one line
    bus, where = open_command_bus(args, command="skin view", config=config,
                                  sends=args.ask_by_sdo, resilient=True, rcvbuf=args.rcvbuf)
    with bus:
        source: BusForces | BusDecode = BusDecode(bus, config) if args.decode and config \
            else BusForces(bus, force_specs(config),
                           lambda reader: asking(bus, reader.attribution, args))
        return _live(args, source, layout, seconds, where, lambda view, started:
                     f"{time.monotonic() - started:5.1f} s")


def _play(args: argparse.Namespace, config: HostConfig | None, layout: Layout,
          times: RecordingTimes) -> int:
    from skin.commands.view.sources import BusDecode, BusForces, Playback, force_specs

    specs = force_specs(config)

    def make(bus: Any) -> BusForces | BusDecode:
        return BusDecode(bus, config) if args.decode and config else BusForces(bus, specs)

    playback = Playback(args.file, make, fast=args.fast)

    def label(view: SkinView, started: float) -> str:
        now = view.now()
        return f"t {(now if now is not None else times.first) - times.first:7.3f} s"

    return _live(args, playback, layout, args.seconds, args.file, label)


def _live(args: argparse.Namespace, source: BusForces | BusDecode | Playback, layout: Layout,
          seconds: float | None, where: str, label: Any) -> int:
    from skin.commands.common.logs import checks_passed
    from skin.commands.view.live import LiveStats, draw_live, short_switch_interval
    from skin.errors import BusError

    view = SkinView(layout, args.scale, title=view_title(args))
    stats = LiveStats()
    started = time.monotonic()
    deadline = None if seconds is None else started + seconds
    playback = getattr(source, "finished", None)

    def done() -> bool:
        return (deadline is not None and time.monotonic() >= deadline) or \
            (playback is not None and playback()) or _failed(source) is not None

    interactive = sys.stdout.isatty() and not args.snapshot
    with short_switch_interval():
        checks_passed()  # the view begins: warnings go out as they come
        source.start(view)
        try:
            if interactive:
                draw_live(view, done, refresh_hz=args.refresh,
                          label=lambda: label(view, started), stats=stats)
            else:
                while not done():
                    time.sleep(_TICK_S)
        except KeyboardInterrupt:
            pass  # Ctrl-C ends a view normally
        finally:
            source.stop()
    elapsed = time.monotonic() - started
    error = _failed(source)
    if not interactive:
        print(view.text(view.now(), label(view, started)), end="")
    report(args, view, source.figures(), elapsed, where, stats)
    if error is not None:
        raise BusError(f"reading stopped: {error}") from error
    return 0


def _failed(source: BusForces | BusDecode | Playback) -> BaseException | None:
    error = getattr(source, "error", None)
    return error() if callable(error) else error


_SCALE = argtypes.number("force", above=0.0, high=1e4, unit="N")
_REFRESH = argtypes.number("rate", above=0.0, high=1000.0, unit="Hz")
_MOMENT = argtypes.number("seconds", low=0.0, high=10**10, unit="s")
_OUT = argtypes.output_file


def add_subparser(subparsers: Any) -> None:
    from skin.commands.common.busargs import add_rcvbuf_argument
    from skin.commands.common.tool_config import add_config_arguments

    parser = subparsers.add_parser(
        "view", help="every patch's taxels at its place: live, or pictures of a recording",
        description="Show the skin: each patch a 3x3 grid of taxels at its position, Fz as "
                    "colour on a fixed scale, shear as an arrow, invalid taxels with their "
                    "reason; per patch its state, rate and completeness. From a bus (the "
                    "force nodes' PDOs; --decode: the patches' PDOs decoded here) or a "
                    "recording FILE.")
    parser.add_argument("file", nargs="?", metavar="FILE",
                        help="a recording (.log, .asc, .blf, .pcap, .mcap); default: the bus")
    where = parser.add_argument_group("layout (default: a row in node order)")
    where.add_argument("--scene", metavar="NAME", help="patch positions of a scene")
    where.add_argument("--config", metavar="HOST.toml",
                       help="a host config: patches[].position_m, force nodes and their "
                            "COB-IDs (and the patches for --decode)")
    where.add_argument("--layout", nargs="+", metavar="NODE=X,Y",
                       help="patch centres in metres, e.g. 1=0,0 2=0.05,0")
    parser.add_argument("--decode", action="store_true",
                        help="decode the patches' resistance PDOs here (listen-only host of "
                             "--config) instead of reading the force nodes' PDOs")
    parser.add_argument("--scale", type=_SCALE, default=DEFAULT_SCALE_N, metavar="N",
                        help=f"the colour scale's top, in N (default {DEFAULT_SCALE_N:g}; "
                             "bottom 0 N)")
    parser.add_argument("--seconds", type=argtypes.seconds, default=None, metavar="S",
                        help="stop after S seconds (default: Ctrl-C or the recording's end)")
    parser.add_argument("--refresh", type=_REFRESH, default=4.0, metavar="HZ",
                        help="live view redraws per second at most (default 4)")
    parser.add_argument("--fast", action="store_true",
                        help="play FILE as fast as it goes (default: its recorded timing)")
    parser.add_argument("--snapshot", action="store_true",
                        help="print one frame as plain text: after --seconds (default 1) on "
                             "a bus, at --at T in FILE")
    parser.add_argument("--at", type=_MOMENT, default=None, metavar="T",
                        help="seconds from FILE's first frame (default: its end)")
    _add_picture_arguments(parser)
    parser.add_argument("--json", type=_OUT, metavar="FILE", help="write the summary as JSON")
    from skin.commands.view.zenoh import add_zenoh_arguments

    add_zenoh_arguments(parser)
    add_rcvbuf_argument(parser)
    add_config_arguments(parser, config=False)
    argtypes.add_bus_arguments(parser)
    parser.set_defaults(func=_view)


def _add_picture_arguments(parser: argparse.ArgumentParser) -> None:
    pictures = parser.add_argument_group("pictures of FILE (matplotlib: the plot extra)")
    pictures.add_argument("--png", type=_OUT, metavar="F.png", help="one moment (--at)")
    pictures.add_argument("--gif", type=argtypes.output_file, metavar="F.gif",
                          help="an animation (--from, --to, --fps)")
    pictures.add_argument("--mp4", type=_OUT, metavar="F.mp4", help="an animation; needs ffmpeg")
    pictures.add_argument("--from", dest="start", type=_MOMENT, default=None, metavar="T0",
                          help="span start, s from FILE's first frame (default 0)")
    pictures.add_argument("--to", dest="end", type=_MOMENT, default=None, metavar="T1",
                          help="span end (default: FILE's end)")
    pictures.add_argument("--fps", type=argtypes.count("fps", 1, 100), default=None, metavar="N",
                          help=f"animation frames per second (default {DEFAULT_FPS:g})")
    pictures.add_argument("--plot", type=argtypes.output_file, metavar="F.png",
                          help="Fx, Fy, Fz of one taxel over time (--patch, --taxel)")
    pictures.add_argument("--patch", type=argtypes.node_id, metavar="N", help="patch node-ID")
    pictures.add_argument("--taxel", type=argtypes.count("taxel", 0, 8), default=None, metavar="K",
                          help="taxel 0..8")
    pictures.add_argument("--raw", action="store_true",
                          help="also the taxel's raw resistances, from the patch's own PDOs")
