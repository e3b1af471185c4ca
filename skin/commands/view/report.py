"""``skin view``'s title, and the summary a view prints (and writes as JSON) when it ends."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from skin.commands.view.live import LiveStats
    from skin.commands.view.term import SkinView


def title(file: str | None, decode: bool) -> str:
    """The view's title: ``skin view run.log (decoded)``."""
    how = " (decoded)" if decode else ""
    return f"skin view {Path(file).name}{how}" if file else f"skin view{how}"


def view_title(args: argparse.Namespace) -> str:
    return title(args.file, args.decode)


def report(args: argparse.Namespace, view: SkinView, figures: dict[str, Any], elapsed: float,
            where: str, stats: LiveStats | None, extra: dict[str, Any] | None = None,
            now: float | None = None) -> None:
    from skin.atomic import atomic_write

    patches = view.summary(now)
    samples = sum(p["samples"] for p in patches.values())
    incomplete = sum(p["incomplete"] for p in patches.values())
    print(f"{len(patches)} patch{'es' if len(patches) != 1 else ''}: {samples:,} samples, "
          f"{incomplete:,} incomplete, in {elapsed:.1f} s from {where}")
    for patch, p in patches.items():
        node = f" (force node {p['force_node']})" if p["force_node"] is not None else ""
        print(f"  patch {patch}{node}: {p['state']}, {p['samples']:,} samples, "
              f"{p['incomplete']:,} incomplete, {p['rate_hz']:.1f} Hz, "
              f"{p['complete_pct']:.0f} % complete in the last second")
    if stats is not None and stats.redraws:
        print(f"view: {stats.redraws} redraws ({stats.redraws_skipped} skipped)")
    if figures.get("unattributed"):
        from skin.commands.view.sources import warn_unattributed

        warn_unattributed(where, {int(c, 16): n for c, n in figures["unattributed"].items()})
    if args.json:
        record = {"source": where, "decode": bool(args.decode), "seconds": round(elapsed, 3),
                  "scale_N": args.scale, "samples": samples, "incomplete": incomplete,
                  "patches": patches, "figures": figures,
                  "view": None if stats is None else
                  {"redraws": stats.redraws, "redraws_skipped": stats.redraws_skipped}}
        record |= extra or {}
        with atomic_write(args.json) as handle:
            handle.write(json.dumps(record, indent=2).encode() + b"\n")
