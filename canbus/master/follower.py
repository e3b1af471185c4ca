"""Listen-only: another master runs the patches (or a recording is replayed onto the bus),
and the host only decodes.

It transmits nothing (no scan, SDO, NMT, SYNC, force node or force PDO). Each patch's
channel is built from the config (:func:`~canbus.master.patch_setup.plan_setup`: the
mapping the host would write for its mode, on a CAN FD bus the one-frame answer;
constants and R0 as a patch holding the configured ones reports them); every SYNC
received opens a cycle (:class:`~canbus.master.sync_producer.SyncFollower`). A patch is
decoded while it is OPERATIONAL as the bus shows it: the NMT commands any master sends
it, its boot-up, its heartbeats (lost and back as an active host sees them).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from types import MappingProxyType

from canbus.master.buslink import BusLink
from canbus.master.discovery import UnknownNode
from canbus.master.patch_setup import PatchSetup, configured_info, plan_setup
from canbus.master.policy import HostParts
from canbus.master.records import PatchRecord

logger = logging.getLogger(__name__)

NMT_COB_ID = 0x000
NMT_START, NMT_STOP, NMT_PRE_OPERATIONAL = 0x01, 0x02, 0x80
OPERATIONAL_STATE, STOPPED_STATE, PRE_OPERATIONAL_STATE = 0x05, 0x04, 0x7F
NMT_COMMANDS = MappingProxyType({NMT_START: OPERATIONAL_STATE, NMT_STOP: STOPPED_STATE,
                                 NMT_PRE_OPERATIONAL: PRE_OPERATIONAL_STATE, 0x81: None,
                                 0x82: None})
"""The NMT state a command (from any master) puts a patch in; None: a reset, after which
the patch boots (pre-operational)."""


class ListenOnly:
    """The host follows what the bus shows (module docstring)."""

    def __init__(self, parts: HostParts) -> None:
        self.parts = parts
        self._nmt: dict[str, Callable[[int, bytearray, float], None]] = {}

    def prepare(self) -> None:
        """The channels are known from the config: decoders built (and tables warmed)
        before any frame, no set-up job."""
        for patch in self.parts.patches.values():
            setup = plan_setup(patch.node_id, patch.node.object_dictionary, patch.config.mode,
                               configured_info(patch.config), fd=patch.link.fd)
            self.parts.states.planned(patch.node_id, setup)
            self.parts.decoders.get(patch.config, setup)

    def planned(self, patch: PatchRecord) -> PatchSetup:
        setup = self.parts.states.view(patch.node_id).setup
        assert setup is not None, "prepare() plans every patch"
        return setup

    def subscribe(self) -> None:
        parts = self.parts
        for patch in parts.patches.values():
            # EMCY only: no SDO client taking the bus's responses
            patch.link.network.subscribe(0x80 + patch.node_id, patch.node.emcy.on_emcy)
            patch.link.monitor.watch(patch.node_id, judged=True)
        for name, link in parts.links.items():
            handler = self._nmt_handler(link)
            self._nmt[name] = handler
            link.network.subscribe(NMT_COB_ID, handler)

    def start(self) -> None:
        """Nothing to start: the bus drives the host."""

    def stop(self) -> None:
        parts = self.parts
        for patch in parts.patches.values():
            _unsubscribe(patch.link, 0x80 + patch.node_id, patch.node.emcy.on_emcy)
        for name, handler in self._nmt.items():
            _unsubscribe(parts.links[name], NMT_COB_ID, handler)
        self._nmt.clear()

    # -- bus events ---------------------------------------------------------------------

    def on_unknown_boot(self, link: BusLink, node_id: int) -> None:
        self.parts.report_unknown(UnknownNode(node_id, None, "booted; not in the config "
                                              f"(listen-only, bus {link.name!r}: not "
                                              "identified)"))

    def on_patch_boot(self, patch: PatchRecord) -> None:
        logger.debug("patch %d booted", patch.node_id)  # its state line follows
        self.parts.states.booted(patch.node_id)

    def on_return(self, patch: PatchRecord, state: int) -> None:
        self.parts.states.returned(patch.node_id, state)

    def on_change(self, patch: PatchRecord, state: int) -> None:
        """A heartbeat entered or left OPERATIONAL (an NMT command we did not see)."""
        self.parts.states.saw_nmt(patch.node_id, state)

    def on_lost(self, patch: PatchRecord) -> None:
        self.parts.states.recheck(patch.node_id)

    def _nmt_handler(self, link: BusLink) -> Callable[[int, bytearray, float], None]:
        def on_nmt(can_id: int, data: bytearray, timestamp: float) -> None:
            """An NMT command from any master. Start: the patch is decoded from now on, and
            if its heartbeat was not heard (lost, or not yet) it must come within
            ``lost_after`` or the patch is lost. Stop, pre-operational, resets: a patch
            heard and not lost goes offline (a reset's boot-up follows)."""
            if len(data) != 2 or data[0] not in NMT_COMMANDS:
                return
            state, target = NMT_COMMANDS[data[0]], data[1]
            parts = self.parts
            for node_id in (list(parts.patches) if target == 0 else [target]):
                patch = parts.patches.get(node_id)
                if patch is None or patch.link is not link:
                    continue
                start = state == OPERATIONAL_STATE
                if start and not link.monitor.alive(node_id):
                    link.monitor.expect(node_id)
                parts.states.saw_nmt(node_id, state, heard=start)
        return on_nmt


def _unsubscribe(link: BusLink, cob_id: int,
                 callback: Callable[[int, bytearray, float], None]) -> None:
    if callback in link.network.subscribers.get(cob_id, []):
        link.network.unsubscribe(cob_id, callback)
