"""What the host knows of one patch, and what it reports of it."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import canopen
import numpy as np
from numpy.typing import NDArray

from canbus.master.buslink import BusLink
from canbus.master.dataplane import ForceFrame, PatchChannel
from canbus.master.forcenode import ForceNode
from canbus.master.hostconfig import PatchConfig
from canbus.master.patchstate import STATES
from skin.constants import TAXELS_PER_PATCH

__all__ = ("STATES", "PatchHealth", "PatchRecord")


@dataclass(frozen=True)
class PatchHealth:
    """One patch as the host sees it.

    ``state``: ``absent`` (never heard), ``configuring``, ``operational``, ``lost``
    (heartbeat overdue) or ``failed`` (set-up refused for a reason that cannot change
    until the node boots again: not a patch, a mapping it cannot take; ``error`` says
    why). A set-up that fails for any other reason is retried while the patch beats: it
    stays ``configuring``, ``error`` says why the last attempt failed and
    ``setup_failures`` counts them. Listen-only: ``configuring`` is pre-operational
    (booted, not started by its master), ``stopped`` is stopped by an NMT command;
    ``failed`` does not occur.
    """

    state: str
    lost: bool
    faulty_taxels: tuple[int, ...]  # reported by EMCY, masked in the output
    last_heartbeat_unix_s: float | None  # the last heartbeat, time.time() (Unix epoch), s
    samples: int  # force frames published for the patch
    incomplete: int  # of which incomplete
    error: str | None = None
    bus: str = "default"  # the bus the patch is on
    setup_failures: int = 0  # set-up attempts that failed, over the host's life
    state_changes: int = 0
    history: tuple[tuple[float, str, str | None], ...] = ()
    """The latest state changes (at most 16): ``(time.time(), state, reason)``."""
    emcys: int = 0  # EMCYs received from the patch
    force_conflict: str | None = None
    """Another node transmits at the force node's ID (its boot-up, heartbeat or EMCY was
    heard): the force node keeps publishing, but a master may read the other's frames."""

    def as_json(self) -> dict[str, Any]:
        """The record as ``--json`` writes it: every time named with its clock and unit
        (``last_heartbeat_unix_s``; each state change ``{"unix_s", "state", "reason"}``)."""
        out = asdict(self)
        out["history"] = [{"unix_s": t, "state": state, "reason": reason}
                          for t, state, reason in self.history]
        return out


@dataclass
class PatchRecord:
    """A configured patch: its node, its force node, its buses, its channel."""

    config: PatchConfig
    link: BusLink  # the patch's bus
    force_link: BusLink  # its force node's bus
    node: canopen.RemoteNode
    force_node: ForceNode
    masked: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(TAXELS_PER_PATCH, bool))
    channel: PatchChannel | None = None  # decoded now (None: offline)
    samples: int = 0
    incomplete: int = 0
    last: ForceFrame | None = None
    force_conflict: str | None = None

    @property
    def node_id(self) -> int:
        return self.config.node_id

    @property
    def force_id(self) -> int:
        return self.config.force_node
