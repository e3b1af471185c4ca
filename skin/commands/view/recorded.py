"""``skin view FILE`` without playing it: one moment (a snapshot or a PNG), an animation of a
span (GIF, MP4), or one taxel's trace."""

from __future__ import annotations

import argparse
import json
import time
from typing import TYPE_CHECKING, Any

from skin.commands.view.layout import Layout
from skin.commands.view.report import report, title, view_title
from skin.commands.view.term import SkinView

if TYPE_CHECKING:
    from canbus.master.hostconfig import HostConfig
    from skin.commands.view.sources import RecordingTimes

DEFAULT_FPS = 10


def moment_view(path: str, t: float, layout: Layout, scale_N: float, *,
                config: HostConfig | None = None, decode: bool = False) -> SkinView:
    """The view of recording ``path`` at bus time ``t``: every sample up to ``t`` filed."""
    from skin.commands.view.sources import force_specs, recorded_samples

    samples = recorded_samples(path, until=t, specs=force_specs(config),
                               decode=config if decode else None)
    view = SkinView(layout, scale_N, title=title(path, decode))
    for sample in samples:
        view.update(sample)
    return view


def at_time(args: argparse.Namespace, times: RecordingTimes, value: float | None,
        flag: str) -> float:
    """A time in s from the recording's first frame -> bus time; refused past its end."""
    from skin.errors import ConfigError

    duration = times.last - times.first
    if value is None:
        return times.last
    if value > duration + 1e-9:
        raise ConfigError(flag, f"{value:g} s is past the recording's end ({duration:.3f} s)")
    return times.first + value


def moment(args: argparse.Namespace, config: HostConfig | None, layout: Layout,
            times: RecordingTimes) -> int:
    started = time.monotonic()
    t = at_time(args, times, args.at, "--at")
    view = moment_view(args.file, t, layout, args.scale, config=config, decode=args.decode)
    label = f"t {t - times.first:.3f} s"
    extra: dict[str, Any] = {"at_s": round(t - times.first, 6)}
    if args.snapshot:
        print(view.text(t, label), end="")
    else:
        from skin.commands.view.plot import moment_picture, pyplot, save_png

        picture = moment_picture(view.state(t), scale_N=args.scale, time_s=t - times.first,
                                 title=view_title(args))
        try:
            save_png(picture, args.png)
        finally:
            pyplot("--png").close(picture.figure)
        print(f"wrote {args.png} (t = {t - times.first:.3f} s)")
        extra["png"] = args.png
    if args.json or not args.snapshot:
        report(args, view, {"frames": times.frames}, time.monotonic() - started, args.file,
                None, extra, now=t)
    return 0


def animation(args: argparse.Namespace, config: HostConfig | None, layout: Layout,
               times: RecordingTimes) -> int:
    from skin.commands.view.plot import figure_size, save_animation
    from skin.commands.view.sources import force_specs, recorded_samples

    started = time.monotonic()
    begin = at_time(args, times, args.start or 0.0, "--from")
    end = at_time(args, times, args.end, "--to")
    fps = args.fps or DEFAULT_FPS
    samples = recorded_samples(args.file, until=end, specs=force_specs(config),
                               decode=config if args.decode else None)
    whole = layout.including({s.patch for s in samples})
    view = SkinView(whole, args.scale, title=view_title(args))
    size = figure_size(view.state(begin))
    path = args.gif or args.mp4

    def moments() -> Any:
        k, frame = 0, 0
        while (t := begin + frame / fps) <= end + 1e-9:
            while k < len(samples) and samples[k].timestamp <= t:
                view.update(samples[k])
                k += 1
            yield view.state(t), t - times.first
            frame += 1

    frames = save_animation(moments(), path, fps=fps, scale_N=args.scale, title=view_title(args),
                            size=size)
    print(f"wrote {path}: {frames} frames at {fps} fps, t = {begin - times.first:.3f} to "
          f"{end - times.first:.3f} s")
    report(args, view, {"frames": times.frames}, time.monotonic() - started, args.file, None,
            {"animation": path, "animation_frames": frames, "fps": fps}, now=end)
    return 0


def trace(args: argparse.Namespace, config: HostConfig | None, times: RecordingTimes) -> int:
    import numpy as np

    from skin.commands.view.plot import save_trace
    from skin.commands.view.sources import (
        force_specs,
        recorded_resistances,
        recorded_samples,
        unattributed_text,
        warn_unattributed,
    )
    from skin.errors import ConfigError

    begin = at_time(args, times, args.start or 0.0, "--from")
    end = at_time(args, times, args.end, "--to")
    unattributed: dict[int, int] = {}
    samples = [s for s in recorded_samples(args.file, until=end, specs=force_specs(config),
                                           decode=config if args.decode else None,
                                           unattributed=unattributed)
               if s.patch == args.patch and s.timestamp >= begin]
    if not samples:
        raise ConfigError("--patch", f"patch {args.patch} has no force sample in {args.file} "
                          f"between {begin - times.first:g} and {end - times.first:g} s"
                          + (f"; {unattributed_text(unattributed)}" if unattributed else ""))
    warn_unattributed(args.file, unattributed)
    t = [s.timestamp - times.first for s in samples]
    force = np.array([s.force_N[args.taxel] for s in samples])
    valid = np.array([bool(s.valid[args.taxel]) for s in samples])
    raw_t, raw = None, None
    if args.raw:
        raws = [r for r in recorded_resistances(args.file, args.patch, until=end,
                                                config=config) if r.timestamp >= begin]
        if not raws:
            raise ConfigError("--raw", f"patch {args.patch} sent no resistance PDO in "
                              f"{args.file} in that span")
        raw_t = [r.timestamp - times.first for r in raws]
        raw = np.array([r.resistance_ohm[args.taxel] for r in raws])
    save_trace(args.plot, times=t, force_N=force, valid=valid, patch=args.patch,
               taxel=args.taxel, title=view_title(args), raw_times=raw_t, raw_ohm=raw)
    print(f"wrote {args.plot}: patch {args.patch} taxel {args.taxel}, {len(samples)} samples"
          f" ({int((~valid).sum())} invalid){f', {len(raw_t)} raw' if raw_t else ''}")
    if args.json:
        from skin.atomic import atomic_write

        record = {"source": args.file, "patch": args.patch, "taxel": args.taxel,
                  "samples": len(samples), "invalid": int((~valid).sum()),
                  "raw_samples": 0 if raw_t is None else len(raw_t), "plot": args.plot,
                  "peak_Fz_N": float(np.max(np.where(valid, force[:, 2], -np.inf)))
                  if valid.any() else None}
        with atomic_write(args.json) as handle:
            handle.write(json.dumps(record, indent=2).encode() + b"\n")
    return 0
