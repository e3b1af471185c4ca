"""Which node sent a PDO, and how that is known: no value is shown under a node that did
not send it.

A PDO's identifier does not say who sent it. CiA 301's predefined connection set gives
node N's TPDO k a default COB-ID (0x180 + N for TPDO 1, ...), but a master may give any
PDO any free identifier (an SDO write of 0x1800+k-1:01, or a host config's
``force_cob_ids``: ``examples/host.toml`` puts force node 100's seven PDOs on
0x1E0..0x1E6, the default TPDO 1 of nodes 96..102). So a frame is attributed to node N's
PDO k only when one of these says so, and is otherwise *unattributed*: named by its
COB-ID, never decoded.

1. **config**: the user's configuration (``--config HOST.toml``: its patches with the
   mapping of their mode, its force nodes at their ``force_cob_ids`` or predefined
   COB-IDs, its ``other_nodes`` at their predefined TPDO 1..4), or a caller's pinned
   COB-IDs (:class:`KnownNode`);
2. **sdo**: an SDO transfer on the bus wrote or read N's PDO COB-ID (what a master
   configuring the node does, and what ``--ask-by-sdo`` asks for);
3. **default**: N's default COB-ID, while N is known to use its defaults: its heartbeat
   was seen (it exists), no SDO transfer set that PDO's COB-ID, and N was seen sending
   *every* TPDO of its current mapping at its default COB-IDs within one sample period
   (one SYNC period; any time, on a bus without SYNC). One frame at a default COB-ID
   proves nothing (it may be another node's remapped PDO, as above); a node's whole set
   of TPDOs, together, while its heartbeat runs, is that node.

An explicit claim (1, 2) wins over a default one (3): a default COB-ID that a config or
an SDO transfer gives to another node is not the default node's, and a node one of whose
defaults is so claimed is never confirmed by its defaults. A COB-ID claimed by two nodes
at the same level is attributed to neither. A boot-up of N forgets what SDO transfers said
about its PDOs and its confirmation: a node that resets starts from its stored (usually
default) parameters, and a master that configures it again is seen again.

What cannot be told apart on the wire: a node remapped without an SDO transfer on this bus
onto *all* the default COB-IDs of another node that is alive and itself remapped. Only
a config (or ``--ask-by-sdo``) settles that; :meth:`Attribution.silent_nodes` names the
nodes whose heartbeat runs while none of their default PDOs come, which is how such a
remap shows.

Which TPDOs confirm a node: :func:`confirming_tpdos` (every TPDO of the node's current
mapping). A PDO a node sends only on an event (not with every sample) would be left out
there.
"""

from __future__ import annotations

import statistics
import threading
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from canbus.pdo_codec import TpdoLayout
from canbus.tools.pdo_dictionary import Dictionary
from canbus.tools.pdo_names import EdsChoice, NodeView, PdoEntry

CONFIG, SDO, DEFAULT = "config", "sdo", "default"
NO_SYNC_WINDOW_S = float("inf")
"""How close in time a node's TPDOs must be to confirm it when no SYNC was seen: any."""
_SYNC_INTERVALS = 8
_FOREIGN_TPDO_BASES = (0x180, 0x280, 0x380, 0x480)


@dataclass(frozen=True, slots=True)
class Owner:
    """Who sends a COB-ID: node ``node``'s ``kind`` (TPDO/RPDO) ``number``, and how we know."""

    node: int
    kind: str
    number: int
    source: str  # CONFIG, SDO or DEFAULT

    @property
    def label(self) -> str:
        return f"{self.kind}{self.number}"


@dataclass(frozen=True)
class KnownNode:
    """What the user's configuration says of a node.

    ``eds``: its EDS (a path or a shipped name), None for a node canskin has no EDS for
    (a host config's ``other_nodes``: its predefined TPDO 1..4 are its, undecoded).
    ``layouts``: its whole TPDO mapping; ``cob_ids``: only its TPDO COB-IDs (TPDO 1, 2, ...);
    neither: its EDS defaults, as the configuration says it keeps them.
    """

    node_id: int
    eds: EdsChoice | None
    layouts: tuple[TpdoLayout, ...] | None = None
    cob_ids: tuple[int, ...] | None = None


def confirming_tpdos(view: NodeView) -> list[PdoEntry]:
    """The TPDOs whose default COB-IDs must all be seen together to confirm the node."""
    return [entry for entry in view.pdos.values() if entry.kind == "TPDO"]


class Attribution:
    """The owner of every PDO COB-ID on a bus, by the rule of the module docstring.

    Feed it what the bus shows (:meth:`heartbeat`, :meth:`sync`, :meth:`frame`; SDO values
    go to ``dictionary.observe`` as before) and ask :meth:`owner`. Whenever an owner may have
    changed, ``dictionary.version`` grows (so caches keyed on it are rebuilt).
    """

    def __init__(self, dictionary: Dictionary, known: Iterable[KnownNode] = ()) -> None:
        self.dictionary = dictionary
        self.known = {k.node_id: k for k in known}
        self.alive: set[int] = set()
        self.confirmed: set[int] = set()
        self.heartbeats: dict[int, float] = {}  # node -> its last heartbeat's bus time
        self.boots: dict[int, float] = {}  # node -> its last boot-up's bus time
        self.named_at: dict[int, float] = {}  # node -> bus time of the first frame that
        # confirmed it by its defaults
        self._foreign: dict[int, Owner] = {}
        self._lock = threading.RLock()
        self._last: dict[int, float] = {}  # candidate default COB-ID -> last frame time
        self._candidates: dict[int, list[int]] = {}  # default COB-ID -> unconfirmed nodes
        self._sync_times: deque[float] = deque(maxlen=_SYNC_INTERVALS + 1)
        self._table: dict[int, Owner] = {}
        self._claimed: dict[int, set[int]] = {}
        self._built = -1
        for node in self.known.values():
            self._pin(node)

    # -- what the bus shows -------------------------------------------------------------

    def heartbeat(self, node: int, state: int | None, timestamp: float) -> None:
        """A heartbeat (``state`` 0: a boot-up) of ``node``."""
        with self._lock:
            self.heartbeats[node] = timestamp
            if state == 0:
                self.boots[node] = timestamp
            new = node not in self.alive
            self.alive.add(node)
            if state == 0 and not new:
                self._forget(node)
            elif new:
                self._built = -1  # the node's defaults become candidates

    def sync(self, timestamp: float) -> None:
        self._sync_times.append(timestamp)

    def frame(self, cob_id: int, timestamp: float, length: int = 8) -> None:
        """A PDO-shaped frame (an 11-bit data frame outside the CANopen services): it may
        be the last of a node's default TPDOs to confirm it. A CAN FD frame longer than 8
        bytes at an alive node's default TPDO 1 is that node's whole sample in one PDO
        (canskin's CAN FD mapping, ``NodeView.fd_frame``): TPDO 1 alone then confirms it."""
        self._refresh()
        nodes = self._candidates.get(cob_id)
        if nodes is None:
            return
        with self._lock:
            if length > 8:
                for node in nodes:
                    view = self.dictionary.view(node)
                    if view is not None and view.fd_frame(cob_id, length):
                        self.dictionary.version += 1
                self._refresh()
            self._last[cob_id] = timestamp
            nodes = self._candidates.get(cob_id, [])
            for node in list(nodes):
                since = self._complete(node)
                if since is not None:
                    self.named_at[node] = since
                    self.confirmed.add(node)
                    self._built = -1
                    self.dictionary.version += 1

    # -- who sends what -----------------------------------------------------------------

    def owner(self, cob_id: int) -> Owner | None:
        """The node that sends ``cob_id``, or None: unattributed."""
        self._refresh()
        return self._table.get(cob_id)

    def table(self) -> dict[int, Owner]:
        """Every attributed COB-ID."""
        self._refresh()
        return dict(self._table)

    def defaults_of(self, node: int) -> set[int]:
        """The COB-IDs ``node`` would send on by its view's current mapping."""
        view = self.dictionary.view(node)
        return set() if view is None else set(view.pdos)

    def silent_nodes(self) -> list[int]:
        """Nodes whose heartbeat runs while none of their PDO COB-IDs carries an attributed
        frame yet: remapped where this bus did not show it, or not operational."""
        self._refresh()
        owned = {o.node for o in self._table.values()}
        return sorted(n for n in self.alive if n not in owned)

    # -- internals ----------------------------------------------------------------------

    def _pin(self, node: KnownNode) -> None:
        if node.eds is None:
            for number, base in enumerate(_FOREIGN_TPDO_BASES, start=1):
                cob = node.cob_ids[number - 1] if node.cob_ids and \
                    number <= len(node.cob_ids) else base + node.node_id
                self._foreign[cob] = Owner(node.node_id, "TPDO", number, CONFIG)
            self.dictionary.assignments[node.node_id] = None  # never decoded as a patch
            return
        self.dictionary.assignments[node.node_id] = node.eds
        view = self.dictionary.view(node.node_id)
        if view is not None and (node.layouts is not None or node.cob_ids is not None):
            view.pin(layouts=node.layouts, cob_ids=node.cob_ids)
        self.dictionary.version += 1

    def _forget(self, node: int) -> None:
        view = self.dictionary.view(node)
        changed = node in self.confirmed
        self.confirmed.discard(node)
        if view is not None and node not in self.known and view.forget_pdo_parameters():
            changed = True
        if changed:
            self._built = -1
            self.dictionary.version += 1

    def _complete(self, node: int) -> float | None:
        """The time of the first of the frames that confirm ``node`` now, or None."""
        view = self.dictionary.view(node)
        if view is None or node in self.confirmed:
            return None
        cobs = [e.layout.cob_id for e in confirming_tpdos(view) if not view.told(e)]
        if not cobs or any(len(self._claimed.get(c, ())) > 1 for c in cobs):
            return None
        times = [self._last.get(c) for c in cobs]
        stamps = [t for t in times if t is not None]
        if len(stamps) < len(times) or max(stamps) - min(stamps) > self._window():
            return None
        return min(stamps)

    def _window(self) -> float:
        times = self._sync_times
        if len(times) < 2:
            return NO_SYNC_WINDOW_S
        return statistics.median(b - a for a, b in zip(times, list(times)[1:], strict=False))

    def _refresh(self) -> None:
        if self._built == self.dictionary.version:
            return
        with self._lock:
            version = self.dictionary.version
            explicit: dict[int, set[Owner]] = {}
            default: dict[int, set[Owner]] = {}
            candidates: dict[int, list[int]] = {}
            for view in self.dictionary.views():
                self._claims(view, explicit, default, candidates)
            for cob, owner in self._foreign.items():
                explicit.setdefault(cob, set()).add(owner)
            table = {cob: next(iter(claims)) for cob, claims in explicit.items()
                     if len(claims) == 1}
            for cob, claims in default.items():
                if cob not in explicit and len(claims) == 1:
                    table[cob] = next(iter(claims))
            claimed: dict[int, set[int]] = {}
            for cob, claims in (*explicit.items(), *default.items()):
                claimed.setdefault(cob, set()).update(o.node for o in claims)
            for cob, nodes in candidates.items():
                claimed.setdefault(cob, set()).update(nodes)
            self._candidates = {cob: nodes for cob, nodes in candidates.items()
                                if cob not in explicit}
            self._claimed = claimed
            self._table = table
            self._built = version

    def _claims(self, view: NodeView, explicit: dict[int, set[Owner]],
                default: dict[int, set[Owner]], candidates: dict[int, list[int]]) -> None:
        node = view.node_id
        known = node in self.known
        for cob, entry in view.pdos.items():
            number = entry.layout.number
            if known or view.told(entry):
                source = CONFIG if known else SDO
                explicit.setdefault(cob, set()).add(Owner(node, entry.kind, number, source))
            elif node in self.confirmed:
                default.setdefault(cob, set()).add(Owner(node, entry.kind, number, DEFAULT))
            elif node in self.alive and entry.kind == "TPDO":
                candidates.setdefault(cob, []).append(node)


def cob_ranges(cob_ids: Sequence[int]) -> str:
    """``0x1E0-0x1E6, 0x2A1``: COB-IDs as runs, for messages."""
    runs: list[list[int]] = []
    for cob in sorted(set(cob_ids)):
        if runs and cob == runs[-1][-1] + 1:
            runs[-1].append(cob)
        else:
            runs.append([cob])
    return ", ".join(f"0x{r[0]:03X}" if len(r) == 1 else f"0x{r[0]:03X}-0x{r[-1]:03X}"
                     for r in runs)
