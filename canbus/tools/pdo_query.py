"""Asking a node for its PDO COB-IDs and mappings by SDO, when the user lets a tool transmit.

A tool that only listens cannot always tell who sends a PDO (:mod:`canbus.tools.attribution`:
a node remapped where the recording or the capture did not show it). A node whose heartbeat
runs can be asked, as any CANopen master may: SDO uploads of each TPDO's COB-ID
(0x1800+k:01) and, for a valid one, its mapping (0x1A00+k:00 and its entries), and of a
force node's source patch (0x2001). The answers cross the bus as any master's SDO transfer
does, and the tool's own SDO follower (``ServiceDecoder``, ``PdoSampleReader``) takes the
values from there, as it takes another master's: the asker only sends the requests, with
canopen's SDO client (one transfer at a time, its time-out and its abort codes).

Only nodes whose heartbeat was seen and whose PDOs the tool does not already know (a
config, an SDO transfer) are asked, each once per boot-up.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

import can
import canopen
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from canbus.identity import FORCE_PRODUCT
from canbus.pdo_codec import COB_ID_INVALID
from canbus.tools.attribution import Attribution
from canbus.tools.pdo_names import TPDO_COMM, TPDO_MAP, NodeView

logger = logging.getLogger(__name__)

SOURCE_PATCH = 0x2001
POLL_S = 0.2


class PdoAsker:
    """Asks every alive node whose PDOs are not known (module docstring), on a thread.

    Add :attr:`listener` to the tool's ``can.Notifier`` on ``bus`` (the SDO answers come
    through it), then :meth:`start`; :meth:`stop` ends it. ``asked`` holds each node's
    outcome: ``"answered"``, ``"no answer"`` or the abort.
    """

    def __init__(self, bus: can.BusABC, attribution: Attribution, *,
                 timeout_s: float = 0.5,
                 wanted: Callable[[int], bool] = lambda node: True) -> None:
        self.attribution = attribution
        self.network = canopen.Network(bus)
        self.listener = canopen.network.MessageListener(self.network)
        self.timeout_s = timeout_s
        self.wanted = wanted
        self.asked: dict[int, str] = {}
        self._boots: dict[int, float] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="pdo-asker", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()

    def _run(self) -> None:
        while not self._stop.wait(POLL_S):
            for node in self.due():
                if self._stop.is_set():
                    return
                self.ask(node)

    def due(self) -> list[int]:
        """Alive nodes not asked since their last boot-up whose PDOs are not all known."""
        out = []
        attribution = self.attribution
        for node in sorted(attribution.alive):
            boot = attribution.boots.get(node, 0.0)
            if node in self.asked and self._boots.get(node) == boot:
                continue
            view = attribution.dictionary.view(node)
            if view is None or node in attribution.known or not self.wanted(node):
                continue
            if all(view.told(entry) for entry in view.pdos.values()) and view.pdos:
                continue
            out.append(node)
        return out

    def ask(self, node_id: int) -> str:
        """Ask ``node_id`` now (on the calling thread); the outcome."""
        view = self.attribution.dictionary.view(node_id)
        if view is None:
            return "no EDS"
        self._boots[node_id] = self.attribution.boots.get(node_id, 0.0)
        remote = canopen.RemoteNode(node_id, view.od)
        self.network.add_node(remote)
        remote.sdo.RESPONSE_TIMEOUT = self.timeout_s
        try:
            self._ask_pdos(remote, view)
            if view.product == FORCE_PRODUCT:
                remote.sdo.upload(SOURCE_PATCH, 0)
            outcome = "answered"
        except SdoAbortedError as err:
            outcome = f"abort 0x{err.code:08X}"
        except SdoCommunicationError:
            outcome = "no answer"
        finally:
            self.network.nodes.pop(node_id, None)
        self.asked[node_id] = outcome
        logger.info("node %d asked for its PDOs by SDO: %s", node_id, outcome)
        return outcome

    @staticmethod
    def _ask_pdos(remote: canopen.RemoteNode, view: NodeView) -> None:
        number = 0
        while TPDO_COMM + number in view.od and TPDO_MAP + number in view.od:
            cob = int.from_bytes(remote.sdo.upload(TPDO_COMM + number, 1)[:4], "little")
            if not cob & COB_ID_INVALID:
                count = remote.sdo.upload(TPDO_MAP + number, 0)[0]
                for sub in range(1, count + 1):
                    remote.sdo.upload(TPDO_MAP + number, sub)
            number += 1
