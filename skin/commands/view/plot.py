"""Pictures of the skin with matplotlib (the ``plot`` extra): a moment, an animation, a trace.

A moment (:func:`moment_picture`): every patch at its position (mm, seen from above: +x
right, +y up), its 3x3 taxels coloured by Fz on the fixed scale (inferno, as the terminal
view; a colour bar in N whose pointed ends stand for values beyond the scale), each valid
taxel's Fz written in its corner, its shear (Fx, Fy) as an arrow from its centre (a quarter
of the scale's force, 1.25 N of 5 N, reaches the taxel's edge; a key shows 1 N), invalid
taxels hatched grey with their reason's short code, and per patch its state (coloured
when not live) and rate, its centre of pressure as a ring and its net shear as a thick
arrow from it (green; amber near slip, red and ``SLIP`` when slipping); the time in the
title. An animation (:func:`save_animation`)
is such moments at a fixed rate, written by Pillow (GIF) or ffmpeg (MP4). A trace
(:func:`save_trace`) is one taxel's Fx, Fy, Fz over time, optionally over its pillars'
raw resistances. Every file is written to a temporary name and renamed into place.
"""

from __future__ import annotations

import math
import os
import shutil
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from skin.atomic import atomic_path
from skin.commands.view.contact import ViewContact, view_contact
from skin.commands.view.term import SHEAR_MIN_N, reason_code
from skin.errors import ConfigError

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from skin.commands.view.term import ViewState

DPI = 100
HATCH_GREY = "#9e9e9e"
ARROW_COLOUR = "#00d7ff"
STATE_COLOURS = {"live": "black", "waiting": "#616161", "stale": "#e65100", "lost": "#c62828"}
CONTACT_COLOURS = {"": "#39ff14", "near": "#ffab00", "SLIP": "#d50000"}
"""The CoP ring and net-shear arrow: in contact, near slip, slipping."""


def pyplot(flag: str) -> Any:
    """matplotlib's pyplot on the Agg backend, or a one-line error naming ``flag``."""
    try:
        import matplotlib
    except ModuleNotFoundError as err:
        raise ConfigError(flag, "needs matplotlib: pip install 'canskin[plot]'") from err
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


@dataclass
class Picture:
    """A drawn moment: the figure, its axes and every taxel's centre (mm, data coords)."""

    figure: Any
    axes: Any
    centres: dict[int, list[tuple[float, float]]]
    _drawn: bool = False

    def pixel(self, patch: int, taxel: int) -> tuple[int, int]:
        """(column, row) of a taxel's centre in the PNG :func:`save_png` writes."""
        return self.pixel_at(*self.centres[patch][taxel])

    def pixel_at(self, x_mm: float, y_mm: float) -> tuple[int, int]:
        """(column, row) of a point (mm) in the PNG :func:`save_png` writes."""
        if not self._drawn:  # the layout is fixed at drawing time
            self.figure.canvas.draw()
            self._drawn = True
        x, y = self.axes.transData.transform((x_mm, y_mm))
        height = self.figure.bbox.height
        return round(x), round(height - y)


def _extent_mm(state: ViewState) -> tuple[float, float, float, float]:
    pitch = state.layout.pitch_m * 1000.0
    half = 1.5 * pitch
    xs = [1000.0 * x for x, _ in state.layout.positions.values()] or [0.0]
    ys = [1000.0 * y for _, y in state.layout.positions.values()] or [0.0]
    return (min(xs) - half - pitch, max(xs) + half + pitch,
            min(ys) - half - pitch, max(ys) + half + 1.1 * pitch)


def figure_size(state: ViewState) -> tuple[float, float]:
    x0, x1, y0, y1 = _extent_mm(state)
    width = min(max((x1 - x0) / 22.0 + 2.4, 6.0), 18.0)
    height = min(max((y1 - y0) / 22.0 + 1.4, 4.0), 14.0)
    return round(width * DPI) / DPI, round(height * DPI) / DPI  # whole pixels


def moment_picture(state: ViewState, *, scale_N: float, time_s: float | None,
                   title: str = "skin view", shear_min_N: float = SHEAR_MIN_N,
                   size: tuple[float, float] | None = None, figure: Any = None) -> Picture:
    """Draw ``state`` (module docstring); into ``figure`` (cleared) if given."""
    plt = pyplot("--png")
    from matplotlib import colormaps
    from matplotlib.colors import Normalize

    if figure is None:
        figure = plt.figure(figsize=size or figure_size(state), dpi=DPI, layout="constrained")
    else:
        figure.clear()
    ax = figure.add_subplot()
    pitch = state.layout.pitch_m * 1000.0
    # N per mm: a quarter of the scale (1.25 N of 5 N) reaches the taxel's edge, so arrows
    # stay inside their taxel up to that shear
    pen = _Pen(ax, colormaps["inferno"].with_extremes(bad="#d9d9d9"), Normalize(0.0, scale_N),
               pitch, (scale_N / 4.0) / (0.5 * pitch), shear_min_N,
               inside=_crowded(state, pitch))  # labels inside the patches' top edge, all alike
    centres = {patch: _draw_patch(pen, patch, 1000.0 * x_m, 1000.0 * y_m,
                                  state.statuses.get(patch))
               for patch, (x_m, y_m) in sorted(state.layout.positions.items())}
    _draw_frame(figure, pen, state, title, time_s)
    return Picture(figure, ax, centres)


@dataclass(frozen=True)
class _Pen:
    """What every patch of one picture is drawn with (lengths in mm)."""

    ax: Any
    cmap: Any
    norm: Any
    pitch: float
    arrow_scale: float  # N per mm of arrow
    shear_min_N: float
    inside: bool  # patch labels inside the patch's top edge

    @property
    def half(self) -> float:
        return 1.5 * self.pitch


def _draw_patch(pen: _Pen, patch: int, cx: float, cy: float,
                status: Any) -> list[tuple[float, float]]:
    """One patch at (cx, cy): its Fz map, grid, outline and label, then its taxels; the
    taxels' centres."""
    from matplotlib.patches import Rectangle

    ax, pitch, half = pen.ax, pen.pitch, pen.half
    sample = status.last if status is not None else None
    taxels = [(cx + (k % 3 - 1) * pitch, cy + (k // 3 - 1) * pitch) for k in range(9)]
    fz = np.full(9, np.nan)
    if sample is not None:
        fz = np.where(sample.valid, sample.force_N[:, 2], np.nan)
    ax.imshow(np.ma.masked_invalid(fz.reshape(3, 3)), cmap=pen.cmap, norm=pen.norm,
              origin="lower", extent=(cx - half, cx + half, cy - half, cy + half),
              interpolation="nearest", zorder=1)
    for edge in (-0.5 * pitch, 0.5 * pitch):  # the taxels' borders
        ax.plot([cx + edge, cx + edge], [cy - half, cy + half], color="#8c8c8c",
                linewidth=0.6, zorder=2)
        ax.plot([cx - half, cx + half], [cy + edge, cy + edge], color="#8c8c8c",
                linewidth=0.6, zorder=2)
    ax.add_patch(Rectangle((cx - half, cy - half), 2 * half, 2 * half, fill=False,
                           edgecolor="black", linewidth=1.2, zorder=3))
    state_text = "waiting" if status is None else status.state
    rate = "" if status is None or sample is None else f", {status.rate_hz:.0f} Hz"
    label = f"patch {patch} · {state_text}{rate}"
    tone = STATE_COLOURS.get(state_text, "black")
    if pen.inside:
        ax.text(cx - half + 0.05 * pitch, cy + half - 0.05 * pitch, label, ha="left",
                va="top", fontsize=7, color=tone, zorder=6,
                bbox={"facecolor": "white", "alpha": 0.85, "pad": 1.0, "linewidth": 0})
    else:
        ax.text(cx, cy + half + 0.15 * pitch, label, ha="center", va="bottom", fontsize=9,
                color=tone, zorder=4)
    if sample is None:
        ax.text(cx, cy, "no sample", ha="center", va="center", fontsize=8, color="#555555")
    else:
        _draw_taxels(pen, sample, taxels)
        _draw_contact(ax, view_contact(sample), (cx, cy), half, pen.arrow_scale,
                      pen.shear_min_N)
    return taxels


def _draw_taxels(pen: _Pen, sample: Any, taxels: list[tuple[float, float]]) -> None:
    """Each taxel's Fz in N, or its hatched fault code; the shear arrows."""
    from matplotlib.patches import Rectangle

    ax, pitch = pen.ax, pen.pitch
    u, v, xs, ys = [], [], [], []
    for k, (tx, ty) in enumerate(taxels):
        if not sample.valid[k]:
            ax.add_patch(Rectangle((tx - pitch / 2, ty - pitch / 2), pitch, pitch,
                                   facecolor=HATCH_GREY, hatch="///", edgecolor="#616161",
                                   linewidth=0.0, zorder=2))
            ax.text(tx, ty, reason_code(int(sample.reason[k]))[0], ha="center",
                    va="center", fontsize=8, fontweight="bold", color="#b71c1c", zorder=4)
            continue
        fx, fy, f = (float(c) for c in sample.force_N[k])
        rgba = pen.cmap(pen.norm(f))
        light = 0.2126 * rgba[0] + 0.7152 * rgba[1] + 0.0722 * rgba[2] > 0.45
        ax.text(tx - 0.44 * pitch, ty - 0.44 * pitch, _decimal(f), ha="left",
                va="bottom", fontsize=8, color="black" if light else "white", zorder=4)
        if math.hypot(fx, fy) >= pen.shear_min_N:
            xs.append(tx)
            ys.append(ty)
            u.append(fx)
            v.append(fy)
    if u:
        ax.quiver(xs, ys, u, v, angles="xy", scale_units="xy", scale=pen.arrow_scale,
                  color=ARROW_COLOUR, edgecolor="black", linewidth=0.6, width=0.012,
                  minlength=0.0, zorder=5)


def _draw_frame(figure: Any, pen: _Pen, state: ViewState, title: str,
                time_s: float | None) -> None:
    """The axes around the patches: limits, labels, the 1 N shear key, the Fz colour bar
    and the title."""
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable

    ax = pen.ax
    x0, x1, y0, y1 = _extent_mm(state)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal", adjustable="box", anchor="C")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.quiver([x0 + 0.06 * (x1 - x0)], [y0 + 0.05 * (y1 - y0)], [1.0], [0.0],
                    angles="xy", scale_units="xy", scale=pen.arrow_scale, color=ARROW_COLOUR,
                    edgecolor="black", linewidth=0.6, width=0.012, zorder=5)
    ax.text(x0 + 0.06 * (x1 - x0) + 1.0 / pen.arrow_scale + 1.0, y0 + 0.05 * (y1 - y0),
            "shear 1 N", va="center", fontsize=8)
    bar = figure.colorbar(ScalarMappable(norm=pen.norm, cmap=colormaps["inferno"]), ax=ax,
                          extend="both", shrink=0.9, pad=0.02)
    bar.set_label("normal force Fz (N)")
    when = "" if time_s is None else f"  t = {time_s:.3f} s"
    ax.set_title(f"{title}{when}", fontsize=11, loc="left")


def _draw_contact(ax: Any, contact: ViewContact | None, centre: tuple[float, float],
                  half: float, arrow_scale: float, shear_min_N: float) -> None:
    """The centre of pressure (a ring: red when slipping, amber near slip), the net shear
    as a thick arrow from it, and SLIP or near in the patch's bottom-right corner."""
    if contact is None:
        return
    colour = CONTACT_COLOURS[contact.mark]
    cx, cy = centre
    if contact.cop_m is not None:
        x, y = cx + 1000.0 * contact.cop_m[0], cy + 1000.0 * contact.cop_m[1]
        fx, fy = contact.shear_N
        if math.hypot(fx, fy) >= shear_min_N:
            ax.quiver([x], [y], [fx], [fy], angles="xy", scale_units="xy", scale=arrow_scale,
                      color=colour, edgecolor="black", linewidth=0.8, width=0.02,
                      minlength=0.0, zorder=7)
        ax.plot([x], [y], marker="o", markersize=9, markerfacecolor="none",
                markeredgecolor=colour, markeredgewidth=2.5, zorder=8)
        ax.plot([x], [y], marker="o", markersize=12, markerfacecolor="none",
                markeredgecolor="black", markeredgewidth=0.8, zorder=8)
    if contact.mark:
        ax.text(cx + half - 0.05 * half, cy - half + 0.05 * half, contact.mark, ha="right",
                va="bottom", fontsize=9, fontweight="bold", color="white", zorder=9,
                bbox={"facecolor": colour, "pad": 1.5, "linewidth": 0})


def _decimal(value: float) -> str:
    """One decimal, without a sign on a value that rounds to zero."""
    shown = round(value, 1)
    return f"{shown if shown else 0.0:.1f}"


def _crowded(state: ViewState, pitch: float) -> bool:
    """Some patch has another less than a pitch above it: no room for labels above."""
    half = 1.5 * pitch
    places = [(1000.0 * x, 1000.0 * y) for x, y in state.layout.positions.values()]
    return any(abs(qx - x) < 2 * half and 0 < qy - y < 2 * half + pitch
               for k, (x, y) in enumerate(places) for j, (qx, qy) in enumerate(places)
               if j != k)


def save_png(picture: Picture, path: str | os.PathLike[str]) -> None:
    from skin.atomic import atomic_write

    with atomic_write(path) as handle:
        picture.figure.savefig(handle, format="png", dpi=DPI)


def check_animation_writer(suffix: str) -> None:
    """A one-line error before any work when the writer for ``suffix`` is missing."""
    pyplot("--gif" if suffix == ".gif" else "--mp4")
    if suffix == ".mp4" and shutil.which("ffmpeg") is None:
        raise ConfigError("--mp4", "needs ffmpeg on PATH (e.g. apt-get install ffmpeg); "
                          "--gif needs only Pillow")
    if suffix == ".gif":
        try:
            import PIL  # noqa: F401
        except ModuleNotFoundError as err:
            raise ConfigError("--gif", "needs Pillow: pip install 'canskin[plot]'") from err


def save_animation(moments: Iterable[tuple[ViewState, float]], path: str | os.PathLike[str],
                   *, fps: int, scale_N: float, title: str, size: tuple[float, float],
                   shear_min_N: float = SHEAR_MIN_N) -> int:
    """One moment per frame at ``fps`` into a GIF (Pillow) or MP4 (ffmpeg); the frames."""
    plt = pyplot("--gif")
    from matplotlib import animation

    suffix = Path(path).suffix.lower()
    check_animation_writer(suffix)
    writer: Any = animation.PillowWriter(fps=fps) if suffix == ".gif" else \
        animation.FFMpegWriter(fps=fps)
    figure = plt.figure(figsize=size, dpi=DPI)
    frames = 0
    try:
        with atomic_path(path) as temporary, writer.saving(figure, str(temporary), DPI):
            for state, time_s in moments:
                moment_picture(state, scale_N=scale_N, time_s=time_s, title=title,
                               shear_min_N=shear_min_N, figure=figure)
                writer.grab_frame()
                frames += 1
            if not frames:
                raise ConfigError("--from/--to", "the span holds no frame to draw")
    finally:
        plt.close(figure)
    return frames


def save_trace(path: str | os.PathLike[str], *, times: Sequence[float],
               force_N: NDArray[np.float64], valid: NDArray[np.bool_], patch: int, taxel: int,
               title: str, raw_times: Sequence[float] | None = None,
               raw_ohm: NDArray[np.float64] | None = None) -> None:
    """Fx, Fy, Fz of one taxel over time (gaps where it was invalid, marked below), and
    with ``raw_ohm`` ``(n, 3)`` its pillars' resistances z, x, y in a second panel."""
    plt = pyplot("--plot")
    from skin.atomic import atomic_write

    panels = 2 if raw_ohm is not None else 1
    figure, axes = plt.subplots(panels, 1, figsize=(9, 3.2 * panels + 0.6), dpi=DPI,
                                sharex=True, squeeze=False)
    ax = axes[0][0]
    t = np.asarray(times, dtype=np.float64)
    shown = np.where(np.asarray(valid)[:, None], force_N, np.nan)
    for axis, name, colour in ((0, "Fx", "#1f77b4"), (1, "Fy", "#2ca02c"), (2, "Fz", "#d62728")):
        ax.plot(t, shown[:, axis], label=name, color=colour, linewidth=1.2)
    invalid = t[~np.asarray(valid)]
    if invalid.size:
        ax.plot(invalid, np.zeros_like(invalid), "|", color="black", markersize=10,
                label="invalid")
    ax.axhline(0.0, color="#999999", linewidth=0.6)
    ax.set_ylabel("force (N)")
    ax.legend(loc="upper right", fontsize=8, ncols=4)
    ax.set_title(f"{title}: patch {patch}, taxel {taxel}", loc="left", fontsize=11)
    if raw_ohm is not None and raw_times is not None:
        rx = axes[1][0]
        for pillar, name in enumerate(("R z", "R x", "R y")):
            rx.plot(raw_times, raw_ohm[:, pillar], label=name, linewidth=1.2)
        rx.set_ylabel("resistance (Ω)")
        rx.legend(loc="upper right", fontsize=8, ncols=3)
    axes[-1][0].set_xlabel("time (s from the recording's first frame)")
    figure.tight_layout()
    try:
        with atomic_write(path) as handle:
            figure.savefig(handle, format="png", dpi=DPI)
    finally:
        plt.close(figure)
