"""What the host knows of one patch, and what it reports of it."""

from __future__ import annotations

import threading
from concurrent.futures import Future
from dataclasses import dataclass, field

import canopen
import numpy as np
from numpy.typing import NDArray

from canbus.master.buslink import BusLink
from canbus.master.dataplane import ForceFrame, PatchChannel
from canbus.master.forcenode import ForceNode
from canbus.master.hostconfig import PatchConfig
from canbus.master.patch_setup import PatchSetup
from skin.constants import TAXELS_PER_PATCH

STATES = ("absent", "configuring", "operational", "stopped", "lost", "failed")


@dataclass(frozen=True)
class PatchHealth:
    """One patch as the host sees it.

    ``state``: ``absent`` (never heard), ``configuring``, ``operational``, ``lost``
    (heartbeat overdue) or ``failed`` (set-up refused or timed out; ``error`` says why).
    Listen-only: ``configuring`` is pre-operational (booted, not started by its master),
    ``stopped`` is stopped by an NMT command; ``failed`` does not occur.
    """

    state: str
    lost: bool
    faulty_taxels: tuple[int, ...]  # reported by EMCY, masked in the output
    last_heartbeat_unix_s: float | None  # the last heartbeat, time.time() (Unix epoch), s
    samples: int  # force frames published for the patch
    incomplete: int  # of which incomplete
    error: str | None = None
    bus: str = "default"  # the bus the patch is on


@dataclass
class PatchRecord:
    """A configured patch: its node, its force node, its buses and its state."""

    config: PatchConfig
    link: BusLink  # the patch's bus
    force_link: BusLink  # its force node's bus
    node: canopen.RemoteNode
    force_node: ForceNode
    masked: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(TAXELS_PER_PATCH, bool))
    state: str = "absent"
    error: str | None = None
    setup: PatchSetup | None = None
    channel: PatchChannel | None = None
    generation: int = 0
    queued: bool = False  # a set-up job is queued and has not started
    job: Future[None] | None = None  # the latest set-up job
    samples: int = 0
    incomplete: int = 0
    last: ForceFrame | None = None
    sdo_lock: threading.Lock = field(default_factory=threading.Lock)

    @property
    def node_id(self) -> int:
        return self.config.node_id
