"""The skin in a terminal: every patch a 3x3 grid of taxels at its place (``skin view``).

::

    view = SkinView(Layout.row([1, 2, 3]), scale_N=5.0)
    host.on_forces(view.update)            # or ForceReader.on_sample(view.update): cheap
    console.print(view.renderable())       # rich; or view.text() for plain text

A taxel cell shows its normal force Fz in N (one decimal) and a glyph for its shear
(Fx, Fy): an arrow in its direction (8 directions; ``→`` from ``shear_min_N``, ``⇒``
from ``shear_strong_N``), blank below. On a terminal the cell's background is Fz on a
fixed scale, 0 to ``scale_N`` (matplotlib's *inferno*: black, purple, orange, pale
yellow; a value above the scale keeps the top colour and is shown bold, a pull (Fz < 0)
keeps the bottom one: the number says the truth). An invalid taxel shows its reason's
short code (:data:`REASON_CODES`; ``---``: invalid, and the reason is not on the bus).
Seen from above: +x right, +y up, so taxel 0 is bottom left and taxel 8 top right.

Per patch: its state (``waiting``, ``live``, ``stale``, ``lost``;
:mod:`canbus.tools.sample_tracker`), samples per second and the share of complete samples
over the last second, and its largest Fz; and its contact summary where the sample has one
(:mod:`skin.commands.view.contact`): the net normal force and net shear (``ΣF``), the
centre of pressure in mm (patch frame) with ``◆`` on the taxel nearest it, and ``SLIP``
(at the friction cone) or ``near`` (within its margin). Rendering reads a copy of the
tracker's state; :meth:`SkinView.update` only files the sample, so a producer never waits
for a redraw.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from skin.commands.view.contact import contact_lines, nearest_taxel, view_contact
from skin.commands.view.layout import Layout

if TYPE_CHECKING:
    from rich.console import RenderableType

    from canbus.tools.sample_tracker import PatchStatus, SampleLike, SampleTracker

DEFAULT_SCALE_N = 5.0
SHEAR_MIN_N = 0.1
SHEAR_STRONG_N = 1.0
INFERNO = ("#000004", "#160b39", "#420a68", "#6a176e", "#932667", "#bc3754", "#dd513a",
           "#f37819", "#fca50a", "#f6d746", "#fcffa4")
"""matplotlib's inferno colormap at 0, 0.1, ..., 1 of the scale (the pictures use it too)."""
THIN_ARROWS = "→↗↑↖←↙↓↘"
THICK_ARROWS = "⇒⇗⇑⇖⇐⇙⇓⇘"
UNSPECIFIED = 0xFF
REASON_CODES = {
    "NON_FINITE": ("NaN", "not a finite reading"), "NON_POSITIVE": ("NEG", "negative reading"),
    "OPEN": ("OPN", "open circuit"), "SHORT": ("SHT", "short circuit"),
    "SATURATED": ("SAT", "ADC saturated"), "OUT_OF_RANGE": ("RNG", "outside the decoder's range"),
    "MISSING": ("MIS", "PDO missing"), "FAULTY": ("FLT", "faulty (EMCY)"),
    "EXTRAPOLATED": ("EXT", "outside the training domain"),
}
"""Reason name (``decoder.reasons``) -> (3-letter code, words)."""
CELL_W = 6
BLOCK_W = 22  # a box of 3 cells with a space each side
GAP_W = 2
ROWS = ((6, 7, 8), (3, 4, 5), (0, 1, 2))  # top row first: +y up
STATE_STYLES = {"waiting": "dim", "live": "bold green", "stale": "bold yellow",
                "lost": "bold red"}
INVALID_STYLE = "bold #ff5f5f on #262626"
MARK_STYLES = {"SLIP": "bold white on #c62828", "near": "bold #ffaf00"}
EMPTY_STYLE = "dim"
Segment = tuple[str, str]
Line = list[Segment]


@functools.cache
def reason_code(code: int) -> tuple[str, str]:
    """A reason code -> (3-letter code, words): ``OPN``, ``---`` when not known."""
    if code == UNSPECIFIED:
        return "---", "reason not on the bus"
    from decoder.reasons import reason_name

    name = reason_name(code)
    if name in REASON_CODES:
        return REASON_CODES[name]
    return f"R{code:02d}"[:3], name.lower().replace("_", " ")


def arrow(fx: float, fy: float, shear_min_N: float = SHEAR_MIN_N,
          shear_strong_N: float = SHEAR_STRONG_N) -> str:
    """The shear glyph: ``" "`` below ``shear_min_N``, else an arrow toward (fx, fy)."""
    magnitude = math.hypot(fx, fy)
    if not magnitude >= shear_min_N:
        return " "
    sector = round(math.atan2(fy, fx) / (math.pi / 4)) % 8
    return (THICK_ARROWS if magnitude >= shear_strong_N else THIN_ARROWS)[sector]


def colour(fz: float, scale_N: float) -> str:
    """Fz on the fixed scale -> ``#rrggbb`` (inferno, clipped to its ends)."""
    t = min(max(fz / scale_N, 0.0), 1.0) * (len(INFERNO) - 1)
    k = min(int(t), len(INFERNO) - 2)
    a, b = _rgb(INFERNO[k]), _rgb(INFERNO[k + 1])
    mix = [round(u + (v - u) * (t - k)) for u, v in zip(a, b, strict=True)]
    return "#" + "".join(f"{c:02x}" for c in mix)


def _rgb(hex_colour: str) -> tuple[int, int, int]:
    return int(hex_colour[1:3], 16), int(hex_colour[3:5], 16), int(hex_colour[5:7], 16)


def cell_style(fz: float, scale_N: float) -> str:
    """The rich style of a valid taxel's cell (cached by Fz to 0.01 N)."""
    return _cell_style(round(fz, 2), scale_N)


@functools.lru_cache(maxsize=4096)
def _cell_style(fz: float, scale_N: float) -> str:
    background = colour(fz, scale_N)
    r, g, b = _rgb(background)
    light = 0.2126 * r + 0.7152 * g + 0.0722 * b > 110
    return f"{'bold ' if fz > scale_N else ''}{'black' if light else 'white'} on {background}"


class _Frame:
    """Lines of (text, style) segments as a rich renderable: cheap to draw."""

    def __init__(self, lines: list[Line]) -> None:
        self.lines = lines

    def __rich_console__(self, console: Any, options: Any) -> Any:
        from rich.segment import Segment

        width = options.max_width
        for line in self.lines:
            used = 0
            for text, style in line:
                if used + len(text) > width:
                    text = text[:max(width - used, 0)]
                if text:
                    yield Segment(text, _style(style))
                used += len(text)
                if used >= width:
                    break
            yield Segment.line()


@functools.lru_cache(maxsize=4096)
def _style(text: str) -> Any:
    from rich.style import Style

    return Style.parse(text) if text else None


@dataclass(frozen=True)
class ViewState:
    """What one frame of the view shows: every patch's status at ``now`` (bus time)."""

    now: float | None
    layout: Layout
    statuses: dict[int, PatchStatus]


class SkinView:
    """The live view's model and its renderings (module docstring)."""

    def __init__(self, layout: Layout | None = None, scale_N: float = DEFAULT_SCALE_N, *,
                 shear_min_N: float = SHEAR_MIN_N, shear_strong_N: float = SHEAR_STRONG_N,
                 title: str = "skin view", tracker: SampleTracker | None = None) -> None:
        from canbus.tools.sample_tracker import SampleTracker
        from skin.errors import ConfigError

        if not (math.isfinite(scale_N) and scale_N > 0):
            raise ConfigError("--scale", f"must be a positive number of newtons, got {scale_N}")
        self.layout = layout or Layout()
        self.scale_N = scale_N
        self.shear_min_N, self.shear_strong_N = shear_min_N, shear_strong_N
        self.title = title
        self.tracker = tracker or SampleTracker()
        for patch in self.layout.patches:
            self.tracker.expect(patch)
        self._clock: tuple[float, float] | None = None  # (sample time, monotonic) latest

    def update(self, sample: SampleLike) -> None:
        """File one sample (any thread; cheap: the view is drawn from a copy later)."""
        self.tracker.add(sample)
        self._clock = (float(sample.timestamp), time.monotonic())

    def now(self) -> float | None:
        """Bus time now: the newest sample's timestamp plus the time since it was filed."""
        clock = self._clock
        return None if clock is None else clock[0] + (time.monotonic() - clock[1])

    def state(self, now: float | None = None) -> ViewState:
        at = self.now() if now is None else now
        statuses = self.tracker.status(at)
        return ViewState(at, self.layout.including(statuses), statuses)

    # -- renderings ---------------------------------------------------------------------

    def lines(self, now: float | None = None, label: str | None = None) -> list[Line]:
        """One frame of the view as lines of (text, rich style) segments."""
        state = self.state(now)
        return [*self._header(state, label), [], *self._grid(state), *self._robot(state)]

    def text(self, now: float | None = None, label: str | None = None) -> str:
        """One frame as plain text (no escape codes), lines without trailing spaces."""
        return "\n".join("".join(t for t, _ in line).rstrip()
                         for line in self.lines(now, label)) + "\n"

    def renderable(self, now: float | None = None, label: str | None = None) -> RenderableType:
        """One frame for rich (``Live.update``, ``Console.print``): lines of styled
        segments, cropped to the console's width (no wrapping, no measuring of text)."""
        return _Frame(self.lines(now, label))

    def summary(self, now: float | None = None) -> dict[str, Any]:
        """Every patch's figures, JSON-able."""
        return {str(p): {"force_node": s.force_node, "state": s.state, "samples": s.samples,
                         "incomplete": s.incomplete, "partial": s.partial,
                         "rate_hz": round(s.rate_hz, 2),
                         "complete_pct": round(s.complete_pct, 2)}
                for p, s in self.state(now).statuses.items()}

    def _header(self, state: ViewState, label: str | None) -> list[Line]:
        ramp: Line = [("Fz ", "bold"), ("0 ", "")]
        ramp += [("█", INFERNO[k]) for k in range(len(INFERNO))]
        ramp += [(f" {self.scale_N:g} N", ""), ("  (cell: Fz in N; colour on a terminal)", "dim")]
        title: Line = [(self.title, "bold")]
        if label:
            title.append((f"  {label}", ""))
        title.append((f"  {len(state.statuses)} patch{'es' if len(state.statuses) != 1 else ''}",
                      ""))
        glyphs: Line = [(f"shear → ≥ {self.shear_min_N:g} N, ⇒ ≥ {self.shear_strong_N:g} N; "
                         "+x right, +y up, taxel 0 bottom left", "dim")]
        contact: Line = [("ΣF net force and shear, ◆ centre of pressure (CoP x y in mm), SLIP "
                          "at the friction cone, near within its margin", "dim")]
        lines = [title, ramp, glyphs, contact]
        codes = sorted({int(c) for s in state.statuses.values() if s.last is not None
                        for c, ok in zip(s.last.reason.tolist(), s.last.valid.tolist(),
                                         strict=True) if not ok})
        if codes:
            words = "  ".join(f"{reason_code(c)[0]} {reason_code(c)[1]}" for c in codes)
            lines.append([("invalid: ", "bold"), (words, "")])
        return lines

    def _grid(self, state: ViewState) -> list[Line]:
        places = state.layout.grid()
        if not places:
            return [[("no patch yet", "dim")]]
        columns = max(c for c, _ in places.values()) + 1
        rows = max(r for _, r in places.values()) + 1
        blocks = {}
        for patch, place in places.items():
            blocks[place] = self._block(state.statuses.get(patch), patch)
            time.sleep(0)  # a thread waiting for the GIL (a bus, a host) goes first
        height = len(next(iter(blocks.values())))
        out: list[Line] = []
        for row in range(rows):
            if row:
                out.append([])
            for k in range(height):
                line: Line = []
                for column in range(columns):
                    block = blocks.get((column, row))
                    line += block[k] if block is not None else [(" " * BLOCK_W, "")]
                    if column < columns - 1:
                        line.append((" " * GAP_W, ""))
                out.append(line)
        return out

    def _robot(self, state: ViewState) -> list[Line]:
        """The contacts on the robot's links (docs/robot.md) of the patches' latest samples,
        when they are placed on links (a host's frames: ``--decode --config``); else none."""
        from skin.placement import merge

        placed = [(one, s.last) for s in state.statuses.values()
                  if (one := getattr(s.last, "on_link", None)) is not None]
        if not placed:
            return []
        pitch = max(float(getattr(frame, "pitch_m", 0.0)) for _, frame in placed)
        out: list[Line] = [[], [("on the robot", "bold"),
                                ("  (link frame: point in mm, force on the link in N)", "dim")]]
        contacts = merge([one for one, _ in placed], pitch)
        for c in contacts:
            x, y, z = (1e3 * c.point_m).tolist()
            fx, fy, fz = c.force_N.tolist()
            patches = "+".join(map(str, c.patches))
            out.append([(f"{c.link} (patches {patches})", "bold"),
                        (f"  point ({x:.1f}, {y:.1f}, {z:.1f})  force ({fx:+.2f}, {fy:+.2f}, "
                         f"{fz:+.2f})", "")])
        if not contacts:
            out.append([("no contact", "dim")])
        return out

    def _block(self, status: PatchStatus | None, patch: int) -> list[Line]:
        state = status.state if status is not None else "waiting"
        name = f"patch {patch}"
        head: Line = [(name, "bold"), (state.rjust(BLOCK_W - len(name)), STATE_STYLES[state])]
        last = status.last if status is not None else None
        if status is None or last is None:
            figures: Line = [("no sample yet".ljust(BLOCK_W), "dim")]
        else:
            text = f"{status.rate_hz:5.1f} Hz {status.complete_pct:3.0f}% complete"
            figures = [(text.ljust(BLOCK_W), "yellow" if status.complete_pct < 100 else "")]
        contact = view_contact(last) if last is not None else None
        marked = -1 if contact is None or contact.cop_m is None else \
            nearest_taxel(contact.cop_m, self.layout.pitch_m)
        out = [head, figures, [("┌" + "─" * (BLOCK_W - 2) + "┐", "")]]
        for row in ROWS:
            line: Line = [("│ ", "")]
            line += [self._cell(last, k, k == marked) for k in row]
            line.append((" │", ""))
            out.append(line)
        out.append([("└" + "─" * (BLOCK_W - 2) + "┘", "")])
        out.append([(_peak(last, status).ljust(BLOCK_W), "")])
        first, where = contact_lines(contact, lambda fx, fy: arrow(
            fx, fy, self.shear_min_N, self.shear_strong_N))
        mark = contact.mark if contact is not None else ""
        out.append([(first.ljust(BLOCK_W), "")])
        out.append([(where.ljust(BLOCK_W - 5), ""), (mark.rjust(5), MARK_STYLES.get(mark, ""))])
        return out

    def _cell(self, sample: SampleLike | None, k: int, cop: bool = False) -> Segment:
        if sample is None:
            return "    - ", EMPTY_STYLE
        if not sample.valid[k]:
            return f"{reason_code(int(sample.reason[k]))[0]:>5} ", INVALID_STYLE
        fx, fy, fz = (float(v) for v in sample.force_N[k])
        shown = round(fz, 1) or 0.0  # no "-0.0"
        text = f"{shown:5.1f}{arrow(fx, fy, self.shear_min_N, self.shear_strong_N)}"
        if cop and text[0] == " ":
            text = "◆" + text[1:]
        return text, cell_style(fz, self.scale_N)


def _peak(sample: SampleLike | None, status: PatchStatus | None) -> str:
    if sample is None or status is None:
        return ""
    valid = [k for k in range(9) if sample.valid[k]]
    if not valid:
        return "no valid taxel"
    k = max(valid, key=lambda t: float(sample.force_N[t][2]))
    return f"max Fz {float(sample.force_N[k][2]):4.1f} N taxel {k}"

