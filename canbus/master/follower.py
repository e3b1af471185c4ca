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
from typing import TYPE_CHECKING

from canbus.master.buslink import BusLink
from canbus.master.discovery import UnknownNode
from canbus.master.patch_setup import PatchSetup, configured_info, plan_setup
from canbus.master.records import PatchRecord

if TYPE_CHECKING:
    from canbus.master.host import HostManager

logger = logging.getLogger(__name__)

NMT_COB_ID = 0x000
NMT_START, NMT_PRE_OPERATIONAL = 0x01, 0x80
OPERATIONAL_STATE, STOPPED_STATE = 0x05, 0x04
# The state an NMT command (from any master) puts a patch in.
_NMT_COMMANDS = {NMT_START: "operational", 0x02: "stopped", NMT_PRE_OPERATIONAL: "configuring",
                 0x81: "configuring", 0x82: "configuring"}  # resets: a boot-up follows


class ListenOnly:
    """The host follows what the bus shows (module docstring)."""

    def __init__(self, host: HostManager) -> None:
        self.host = host
        self._nmt: dict[str, Callable[[int, bytearray, float], None]] = {}

    def prepare(self) -> None:
        """The channels are known from the config: decoders built (and tables warmed)
        before any frame, no set-up job."""
        for patch in self.host.patches.values():
            patch.setup = plan_setup(patch.node_id, patch.node.object_dictionary,
                                     patch.config.mode, configured_info(patch.config),
                                     fd=patch.link.fd)
            self.host.decoders.get(patch.config, patch.setup)

    def planned(self, patch: PatchRecord) -> PatchSetup:
        assert patch.setup is not None, "prepare() plans every patch"
        return patch.setup

    def subscribe(self) -> None:
        host = self.host
        for patch in host.patches.values():
            # EMCY only: no SDO client taking the bus's responses
            patch.link.network.subscribe(0x80 + patch.node_id, patch.node.emcy.on_emcy)
            patch.link.monitor.watch(patch.node_id, judged=True)
        for name, link in host.links.items():
            handler = self._nmt_handler(link)
            self._nmt[name] = handler
            link.network.subscribe(NMT_COB_ID, handler)

    def start(self) -> None:
        """Nothing to start: the bus drives the host."""

    def stop(self) -> None:
        host = self.host
        for patch in host.patches.values():
            _unsubscribe(patch.link, 0x80 + patch.node_id, patch.node.emcy.on_emcy)
        for name, handler in self._nmt.items():
            _unsubscribe(host.links[name], NMT_COB_ID, handler)
        self._nmt.clear()

    def follow(self, patch: PatchRecord, state: str) -> None:
        """The patch is now in ``state`` (its master's NMT command or its heartbeat says)."""
        host = self.host
        with host._lock:
            if state != "operational":
                host.take_offline(patch, state)
            elif patch.channel is None and patch.setup is not None:
                host.go_online(patch, patch.setup)

    # -- bus events ---------------------------------------------------------------------

    def on_unknown_boot(self, link: BusLink, node_id: int) -> None:
        self.host.report_unknown(UnknownNode(node_id, None, "booted; not in the config "
                                             f"(listen-only, bus {link.name!r}: not "
                                             "identified)"))

    def on_patch_boot(self, patch: PatchRecord) -> None:
        logger.info("patch %d booted", patch.node_id)
        self.follow(patch, "configuring")

    def on_return(self, patch: PatchRecord, state: int) -> None:
        self.follow(patch, _state_name(state))

    def on_change(self, patch: PatchRecord, state: int) -> None:
        """A heartbeat entered or left OPERATIONAL (an NMT command we did not see)."""
        self.follow(patch, _state_name(state))

    def on_lost(self, patch: PatchRecord) -> None:
        host = self.host
        with host._lock:
            if patch.state not in ("operational", "configuring", "stopped"):
                return
            host.take_offline(patch, "lost")
        logger.warning("patch %d lost (no heartbeat for %.0f ms)", patch.node_id,
                       patch.link.monitor.lost_after_s * 1000)

    def _nmt_handler(self, link: BusLink) -> Callable[[int, bytearray, float], None]:
        def on_nmt(can_id: int, data: bytearray, timestamp: float) -> None:
            """An NMT command from any master. Start: the patch is decoded from now on, and
            if its heartbeat was not heard (lost, or not yet) it must come within
            ``lost_after`` or the patch is lost. Stop, pre-operational, resets: a patch
            heard and not lost goes offline (a reset's boot-up follows)."""
            if len(data) != 2 or data[0] not in _NMT_COMMANDS:
                return
            state, target = _NMT_COMMANDS[data[0]], data[1]
            host = self.host
            for node_id in (list(host.patches) if target == 0 else [target]):
                patch = host.patches.get(node_id)
                if patch is None or patch.link is not link:
                    continue
                if state == "operational":
                    if not link.monitor.alive(node_id):
                        link.monitor.expect(node_id)
                elif patch.state in ("absent", "lost"):
                    continue
                self.follow(patch, state)
        return on_nmt


def _state_name(state: int) -> str:
    """A patch's heartbeat state as a health state."""
    if state == OPERATIONAL_STATE:
        return "operational"
    return "stopped" if state == STOPPED_STATE else "configuring"


def _unsubscribe(link: BusLink, cob_id: int,
                 callback: Callable[[int, bytearray, float], None]) -> None:
    if callback in link.network.subscribers.get(cob_id, []):
        link.network.unsubscribe(cob_id, callback)
