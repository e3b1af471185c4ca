"""What a host policy is, and the narrow part of the host it is given.

A policy (:class:`~canbus.master.active.ActiveMaster`,
:class:`~canbus.master.follower.ListenOnly`) decides what the host does with its patches.
It is handed a :class:`HostParts` by the facade (``canbus.master.host``), never the facade
itself: the records, the buses, the decoders, the patch states (where it records what it
sees: each state is derived there, :mod:`canbus.master.patchstate`), the stop event, and
two services. Whatever else a policy needs (a worker pool, a scan flag, NMT handlers) is
its own.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Protocol

from canbus.master.buslink import BusLink
from canbus.master.decoders import DecoderCache
from canbus.master.discovery import UnknownNode
from canbus.master.hostconfig import HostConfig
from canbus.master.patch_setup import PatchSetup
from canbus.master.patchstate import PatchStates
from canbus.master.records import PatchRecord


@dataclass(frozen=True)
class HostParts:
    """The host as a policy sees it."""

    config: HostConfig
    patches: Mapping[int, PatchRecord]
    links: Mapping[str, BusLink]
    force_ids: Mapping[int, int]  # force node-ID -> its patch
    decoders: DecoderCache
    states: PatchStates
    stopping: threading.Event  # set when the host stops: every wait of a policy ends
    report_unknown: Callable[[UnknownNode], None]
    tare: Callable[[int], None]  # tare a patch (a force node's 0x2007 written by SDO)

    def bus_name(self, link: BusLink) -> str:
        """``the bus``, or ``bus 'name'`` when the host has several, for messages."""
        return "the bus" if len(self.links) == 1 else f"bus {link.name!r}"


class Policy(Protocol):
    """What the host calls on its policy. Bus events arrive on a notifier's thread (the
    heartbeat consumer's for ``on_lost``): record them, never wait for the bus there."""

    def prepare(self) -> None:
        """Before anything listens: what the policy needs built."""

    def planned(self, patch: PatchRecord) -> PatchSetup:
        """The set-up a patch is decoded with before it is configured."""

    def subscribe(self) -> None:
        """Its subscriptions on the buses, before any notifier runs."""

    def start(self) -> None:
        """Everything the bus needs for the patches to run; returns early on ``stopping``."""

    def stop(self) -> None:
        """Undo what :meth:`subscribe` and :meth:`start` did, promptly."""

    def on_patch_boot(self, patch: PatchRecord) -> None: ...

    def on_return(self, patch: PatchRecord, state: int) -> None: ...

    def on_change(self, patch: PatchRecord, state: int) -> None: ...

    def on_lost(self, patch: PatchRecord) -> None: ...

    def on_unknown_boot(self, link: BusLink, node_id: int) -> None: ...
