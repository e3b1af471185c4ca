"""Node-ID -> :class:`~canbus.tools.pdo_names.NodeView`: which EDS decodes which node.

Node-IDs 1..64 get the patch's EDS, 65..127 the force node's (the host's default force node
is patch + 64), unless ``assignments`` say otherwise (``--eds NODE=FILE``; None: a node with
no EDS here); an identity read by SDO (0x1018:02) switches a node to its product's shipped
EDS. Each EDS is parsed once per process and shared by the views of every node using it.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Mapping

import canopen

from canbus.od import load_od
from canbus.tools.pdo_names import SHIPPED_BY_PRODUCT, EdsChoice, NodeView, shipped_default
from skin.errors import ConfigError
from skin.inputs import fields


class Dictionary:
    """Node-ID -> :class:`NodeView`, built on first use; ``assignments`` pin nodes' EDS
    (None: a node with no EDS here, no view).

    Each EDS is parsed once (``canopen.import_od`` takes ~10 ms) and shared by the views
    of every node that uses it, so a burst of new nodes does not stall the receive thread.
    ``version`` grows whenever a view appears or a view's PDO table changes.
    """

    def __init__(self, assignments: Mapping[int, EdsChoice | None] | None = None) -> None:
        self.assignments: dict[int, EdsChoice | None] = dict(assignments or {})
        self._views: dict[int, NodeView | None] = {}
        self._ods: dict[str, tuple[canopen.ObjectDictionary, int]] = {}
        self.version = 0

    def views(self) -> list[NodeView]:
        """Every node's view built so far."""
        return [view for view in list(self._views.values()) if view is not None]

    def view(self, node_id: int) -> NodeView | None:
        """The node's view, or None for a node-ID outside 1..127."""
        if node_id in self._views:
            return self._views[node_id]
        view = None
        eds = self.assignments.get(node_id, shipped_default(node_id))
        if fields.is_node_id(node_id) and eds is not None:  # None: a node without an EDS here
            view = self._new_view(node_id, eds)
        self._views[node_id] = view
        self.version += 1
        return view

    def _new_view(self, node_id: int, eds: EdsChoice) -> NodeView:
        key = os.fspath(eds)
        if key not in self._ods:
            self._ods[key] = (_parsed(key, _stamp(key), node_id), node_id)
        od, od_node_id = self._ods[key]
        return NodeView(node_id, od, od_node_id)


    def observe(self, node_id: int, index: int, subindex: int, raw: bytes) -> None:
        """Feed an SDO value to the node's view (and follow an identity it reveals)."""
        view = self.view(node_id)
        if view is None:
            return
        if (index, subindex) == (0x1018, 2) and node_id not in self.assignments:
            product = int.from_bytes(raw[:4], "little")
            if product in SHIPPED_BY_PRODUCT and product != view.product:
                self._views[node_id] = self._new_view(node_id, SHIPPED_BY_PRODUCT[product])
                self.version += 1
                return
        if view.observe(index, subindex, raw):
            self.version += 1


def _stamp(key: str) -> float:
    """A file's modification time (0 for a shipped name): a changed file is parsed again."""
    try:
        return os.stat(key).st_mtime
    except OSError:
        return 0.0


@functools.lru_cache(maxsize=16)
def _parsed(key: str, stamp: float, node_id: int) -> canopen.ObjectDictionary:
    """An EDS parsed once per process (the views only read it)."""
    return load_od(key, node_id)


def parse_assignment(text: str) -> dict[int, str]:
    """``NODE=FILE`` or ``FIRST-LAST=FILE`` (FILE: a path or a shipped EDS name)."""
    nodes, sep, eds = text.partition("=")
    if not sep or not eds:
        raise ConfigError("--eds", f"expected NODE=FILE or FIRST-LAST=FILE, got {text!r}")
    first, _, last = nodes.partition("-")
    try:
        low, high = int(first, 0), int(last or first, 0)
    except ValueError as err:
        raise ConfigError("--eds", f"{nodes!r} is not a node-ID or range") from err
    if not (fields.is_node_id(low) and fields.is_node_id(high) and low <= high):
        raise ConfigError("--eds", f"node-IDs must be in 1..127, got {nodes!r}")
    load_od(eds, low)  # fail now, with the file's own error, not in the receive thread
    return dict.fromkeys(range(low, high + 1), eds)
