"""Where the patches sit: centres in metres, from a scene, a host config or ``--layout``.

A :class:`Layout` maps a patch's node-ID to the centre (x, y) of its 3x3 taxels, in metres,
seen from above with +x to the right and +y up (taxel k sits at column k % 3, row k // 3
of the patch, so taxel 0 is bottom left). Pictures draw patches at their positions; the
terminal view, which has only character cells, keeps their order: patches are put in
columns by x and rows by y (positions closer than 1.5 taxel pitches share a column or
row), the highest y on top. A patch the layout does not name is added to the right of the
bottom row.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from skin.constants import DEFAULT_CONSTANTS
from skin.errors import ConfigError
from skin.inputs import fields

DEFAULT_PITCH_M = DEFAULT_CONSTANTS.taxel_pitch_m
ROW_SPACING_M = 0.05
"""Centre to centre of patches in a default row: a 45 mm patch and a 5 mm gap."""

POSITION_LIMIT_M = 1000.0


@dataclass(frozen=True)
class Layout:
    """Patch node-ID -> centre (x, y) in metres; ``source`` says where it came from."""

    positions: Mapping[int, tuple[float, float]] = field(default_factory=dict)
    pitch_m: float = DEFAULT_PITCH_M
    source: str = "row"

    @classmethod
    def row(cls, patches: Iterable[int], pitch_m: float = DEFAULT_PITCH_M) -> Layout:
        """The default: a row in node order, 5 cm apart."""
        return cls({p: (ROW_SPACING_M * k, 0.0) for k, p in enumerate(sorted(set(patches)))},
                   pitch_m, "row")

    @property
    def patches(self) -> list[int]:
        return sorted(self.positions)

    def including(self, patches: Iterable[int]) -> Layout:
        """This layout plus ``patches`` it does not name, in node order to the right of the
        bottom row."""
        extra = sorted(set(patches) - set(self.positions))
        if not extra:
            return self
        positions = dict(self.positions)
        if positions:
            x = max(x for x, _ in positions.values()) + ROW_SPACING_M
            y = min(y for _, y in positions.values())
        else:
            x = y = 0.0
        for k, patch in enumerate(extra):
            positions[patch] = (x + ROW_SPACING_M * k, y)
        return Layout(positions, self.pitch_m, self.source)

    def grid(self) -> dict[int, tuple[int, int]]:
        """Patch -> (column, row) of the terminal view; row 0 is the top (highest y)."""
        tolerance = 1.5 * self.pitch_m
        columns = _ranks([x for x, _ in self.positions.values()], tolerance)
        rows = _ranks([y for _, y in self.positions.values()], tolerance)
        top = max(rows.values(), default=0)
        taken: set[tuple[int, int]] = set()
        out = {}
        for patch in self.patches:
            x, y = self.positions[patch]
            column, row = columns[x], top - rows[y]
            while (column, row) in taken:  # two patches at one place: side by side
                column += 1
            taken.add((column, row))
            out[patch] = (column, row)
        return out


def _ranks(values: list[float], tolerance: float) -> dict[float, int]:
    """Each value -> its cluster's rank; values within ``tolerance`` of the previous share."""
    ranks: dict[float, int] = {}
    rank, previous = -1, -math.inf
    for value in sorted(set(values)):
        if value - previous > tolerance:
            rank += 1
        ranks[value] = rank
        previous = value
    return ranks


def parse_layout(texts: Iterable[str], pitch_m: float = DEFAULT_PITCH_M) -> Layout:
    """``--layout NODE=X,Y ...`` (metres) -> a Layout; ConfigError naming a bad entry."""
    positions: dict[int, tuple[float, float]] = {}
    for text in texts:
        node, sep, where = text.partition("=")
        x_text, comma, y_text = where.partition(",")
        try:
            patch = int(node, 0)
            x, y = float(x_text), float(y_text)
        except ValueError:
            patch, x, y = 0, math.nan, math.nan
        if not sep or not comma or not fields.is_node_id(patch) or \
                not (abs(x) <= POSITION_LIMIT_M and abs(y) <= POSITION_LIMIT_M):
            raise ConfigError("--layout", f"expected NODE=X,Y (node-ID 1..127, metres within "
                              f"±{POSITION_LIMIT_M:g}), got {text!r}")
        if patch in positions:
            raise ConfigError("--layout", f"patch {patch} is placed twice")
        positions[patch] = (x, y)
    return Layout(positions, pitch_m, "--layout")


def layout_from_positions(positions: Mapping[int, tuple[float, float] | None], source: str,
                          pitch_m: float = DEFAULT_PITCH_M) -> Layout:
    """From a scene's or host config's patches; those without a position go in a row after."""
    placed = {p: (float(xy[0]), float(xy[1])) for p, xy in positions.items() if xy is not None}
    return Layout(placed, pitch_m, source).including(positions)
