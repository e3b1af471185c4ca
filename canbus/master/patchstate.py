"""Each patch's state, derived in one place from what was seen of it.

The facts of a patch (:class:`Facts`): whether it was ever *heard* (a boot-up, a
heartbeat, an answer to the scan, an NMT start another master sent it); whether it is
*lost* (the heartbeat consumer found its heartbeat overdue and has heard none since:
read from the consumer at every derivation, so an ``on_lost`` handled after a heartbeat
cannot win over it); the NMT state the bus shows (listen-only); the set-up in force for
this *incarnation* of the node (a boot-up begins a new one, and voids a set-up made or
running for the old); the last set-up failure and whether it is permanent.

:func:`derive` is the whole rule. :class:`PatchStates` holds the facts, applies each
change of a fact and derives the state again under one lock, logs every change of state
once (logger ``canbus.master.patchstate``, the :class:`Transition` in the record's
``patch_state``) and hands it, in order, to the host (``apply``: the patch's channel goes
online or offline with it).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Protocol

from canbus.master.patch_setup import PatchSetup

logger = logging.getLogger(__name__)

STATES = ("absent", "configuring", "operational", "stopped", "lost", "failed")
OPERATIONAL, STOPPED = 0x05, 0x04  # NMT state bytes of a heartbeat
HISTORY_KEPT = 16  # state changes of a patch kept for health() and --json
LEVELS = MappingProxyType({"lost": logging.WARNING, "failed": logging.ERROR})


class Liveness(Protocol):
    """What the state needs of a heartbeat consumer (``liveness.HeartbeatMonitor``)."""

    lost_after_s: float

    def lost(self, node_id: int) -> bool: ...


@dataclass
class Facts:
    """What was seen of one patch."""

    heard: bool = False
    lost: bool = False  # read from the heartbeat consumer at each derivation
    nmt: int | None = None  # the NMT state the bus shows (listen-only)
    setup: PatchSetup | None = None  # in force (active) or planned (listen-only)
    configured: bool = False  # the active host's set-up of this incarnation succeeded
    failure: str | None = None  # the last set-up failure of this incarnation
    permanent: bool = False  # ... and it cannot change until the node boots again
    incarnation: int = 0
    failures: int = 0  # set-up failures in this incarnation


def derive(facts: Facts, *, listen_only: bool) -> tuple[str, str | None]:
    """The state of a patch with these facts, and why when it is not as it should be."""
    if not facts.heard:
        return "absent", None
    if facts.permanent:
        return "failed", facts.failure
    if facts.lost:
        return "lost", "no heartbeat"
    if listen_only:
        if facts.nmt == OPERATIONAL:
            return "operational", None
        return ("stopped" if facts.nmt == STOPPED else "configuring"), None
    if facts.configured:
        return "operational", None
    return "configuring", facts.failure


@dataclass(frozen=True)
class Transition:
    """A patch changed state."""

    node_id: int
    old: str
    new: str
    reason: str | None
    time: float  # time.time()


@dataclass
class _Patch:
    monitor: Liveness
    facts: Facts = field(default_factory=Facts)
    state: str = "absent"
    reason: str | None = None
    changes: int = 0
    setup_failures: int = 0  # over the host's life
    history: deque[Transition] = field(default_factory=lambda: deque(maxlen=HISTORY_KEPT))


@dataclass(frozen=True)
class PatchView:
    """One patch's state and what led to it, as read at one moment."""

    state: str
    reason: str | None
    setup: PatchSetup | None
    setup_failures: int
    changes: int
    history: tuple[Transition, ...]


Apply = Callable[[Transition, Facts], None]


class PatchStates:
    """The states of the patches watched by ``monitors`` (node-ID -> its bus's heartbeat
    consumer). ``apply(transition, facts)`` runs under the lock, for every change."""

    def __init__(self, monitors: Mapping[int, Liveness], *, listen_only: bool,
                 apply: Apply | None = None) -> None:
        self.listen_only = listen_only
        self.apply = apply
        self.changed = threading.Condition(threading.RLock())
        self._patches = {n: _Patch(monitor) for n, monitor in monitors.items()}

    # -- facts: each change derives the state again ------------------------------------

    def heard(self, node_id: int) -> str:
        with self.changed:
            self._patches[node_id].facts.heard = True
            return self._derive(node_id)

    def booted(self, node_id: int) -> int:
        """A boot-up: a new incarnation (its set-up starts over); returns it."""
        with self.changed:
            facts = self._patches[node_id].facts
            facts.heard, facts.configured, facts.permanent = True, False, False
            facts.failure, facts.failures = None, 0
            facts.incarnation += 1
            if self.listen_only:
                facts.nmt = None  # pre-operational until its master starts it
            self._derive(node_id)
            return facts.incarnation

    def returned(self, node_id: int, nmt: int) -> str:
        """Heard again (or for the first time) without a boot-up, in NMT state ``nmt``.
        Active: a patch that is not OPERATIONAL lost what the host set (or never had it),
        so its set-up starts over; listen-only: it is in that state."""
        with self.changed:
            facts = self._patches[node_id].facts
            facts.heard = True
            if self.listen_only:
                facts.nmt = nmt
            elif nmt != OPERATIONAL and facts.configured:
                facts.configured = False
                facts.incarnation += 1
            return self._derive(node_id)

    def saw_nmt(self, node_id: int, nmt: int | None, *, heard: bool = False) -> str:
        """Listen-only: the bus shows the patch in NMT state ``nmt`` (a heartbeat or a
        master's command; None: a reset, pre-operational after its boot-up)."""
        with self.changed:
            facts = self._patches[node_id].facts
            facts.nmt = nmt
            facts.heard = facts.heard or heard
            return self._derive(node_id)

    def planned(self, node_id: int, setup: PatchSetup) -> None:
        """Listen-only: the channel the patch is decoded with, known from the config."""
        with self.changed:
            self._patches[node_id].facts.setup = setup

    def set_up(self, node_id: int, incarnation: int, setup: PatchSetup) -> bool:
        """The set-up of ``incarnation`` succeeded; False (ignored) if the node has booted
        (or lost its set-up) since."""
        with self.changed:
            facts = self._patches[node_id].facts
            if facts.incarnation != incarnation:
                return False
            facts.setup, facts.configured = setup, True
            facts.failure, facts.failures, facts.permanent = None, 0, False
            self._derive(node_id)
            return True

    def setup_failed(self, node_id: int, incarnation: int, reason: str, *,
                     permanent: bool) -> int | None:
        """The set-up of ``incarnation`` failed; returns the failures of this incarnation
        so far (None: the node has booted since, the failure is void)."""
        with self.changed:
            patch = self._patches[node_id]
            facts = patch.facts
            if facts.incarnation != incarnation:
                return None
            facts.failure, facts.permanent = reason, permanent
            facts.failures += 1
            patch.setup_failures += 1
            self._derive(node_id)
            return facts.failures

    def recheck(self, node_id: int) -> str:
        """Derive again (the heartbeat consumer found the patch overdue)."""
        with self.changed:
            return self._derive(node_id)

    # -- reading -----------------------------------------------------------------------

    def state(self, node_id: int) -> str:
        with self.changed:
            return self._patches[node_id].state

    def view(self, node_id: int) -> PatchView:
        with self.changed:
            p = self._patches[node_id]
            return PatchView(p.state, p.reason, p.facts.setup, p.setup_failures, p.changes,
                             tuple(p.history))

    def facts(self, node_id: int) -> Facts:
        """A copy of the patch's facts as they are now (``lost`` read afresh)."""
        with self.changed:
            patch = self._patches[node_id]
            return replace(patch.facts, lost=patch.monitor.lost(node_id))

    def needs_setup(self, node_id: int) -> int | None:
        """The incarnation to configure when the active host should (re)configure the
        patch now: heard, not lost, not configured, no permanent failure."""
        with self.changed:
            patch = self._patches[node_id]
            if patch.state != "configuring" or patch.facts.configured:
                return None
            return patch.facts.incarnation

    def wait_for(self, node_ids: Iterable[int], state: str, timeout: float) -> bool:
        wanted = list(node_ids)
        with self.changed:
            return self.changed.wait_for(
                lambda: all(self._patches[n].state == state for n in wanted), timeout)

    def announce(self) -> None:
        """Log every patch's state as it is now (when the host starts)."""
        with self.changed:
            for node_id, patch in self._patches.items():
                self._log(Transition(node_id, patch.state, patch.state, patch.reason,
                                     time.time()))

    # -- the one place a state changes -------------------------------------------------

    def _derive(self, node_id: int) -> str:
        patch = self._patches[node_id]
        patch.facts.lost = patch.monitor.lost(node_id)
        state, reason = derive(patch.facts, listen_only=self.listen_only)
        if state == "lost":
            reason = f"no heartbeat for {patch.monitor.lost_after_s * 1000:.0f} ms"
        if state == patch.state and reason == patch.reason:
            return state
        changed = state != patch.state
        transition = Transition(node_id, patch.state, state, reason, time.time())
        patch.state, patch.reason = state, reason
        if changed:
            patch.changes += 1
            patch.history.append(transition)
            self._log(transition)
            if self.apply is not None:
                try:
                    self.apply(transition, patch.facts)
                except Exception:  # the state stands; what failed to follow it is logged
                    logger.exception("patch %d: applying %s -> %s failed", node_id,
                                     transition.old, transition.new)
        self.changed.notify_all()
        return state

    @staticmethod
    def _log(transition: Transition) -> None:
        detail = f" ({transition.reason})" if transition.reason else ""
        logger.log(LEVELS.get(transition.new, logging.INFO), "patch %d: %s%s",
                   transition.node_id, transition.new, detail,
                   extra={"patch_state": transition})
