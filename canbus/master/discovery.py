# canopen 2.4 ships py.typed but leaves SdoClient and NodeScanner methods unannotated.
# mypy: disable-error-code="no-untyped-call"
"""Finding nodes: boot-up messages, canopen's SDO scan, and identification by object 0x1018.

A node is a *patch* if its identity (0x1018) has product code 1, a *force node* if 2
(eds/skin-patch.eds, eds/skin-forces.eds; vendor 0). Anything else, or a node that does
not answer SDO, is *unknown*: the host reports it and leaves it alone.

SDO transfers wait for responses that arrive on the network's notifier thread, so
nothing here may run on that thread: callbacks only record, a worker identifies.
"""

from __future__ import annotations

import logging
import queue
import struct
import threading
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import canopen
from canopen.sdo.client import SdoClient
from canopen.sdo.constants import RESPONSE_ABORTED
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from canbus.identity import Identity
from skin.inputs import fields

logger = logging.getLogger(__name__)

BOOTUP = 0x00
SDO_FRAME = 8  # bytes of every SDO frame (CiA 301)
RESPONSES_KEPT = 256  # SDO or LSS answers queued at most (a block transfer has <= 127)
_HEARTBEAT = 0x700


@dataclass(frozen=True)
class UnknownNode:
    """A node the host does not manage, as reported to ``on_unknown``."""

    node_id: int
    identity: Identity | None  # None: it did not answer SDO
    reason: str


def bound_lss_answers(network: canopen.Network) -> None:
    """canopen's LSS master queues every frame on 0x7E4 for as long as the network runs,
    whether it asked or not: keep :data:`RESPONSES_KEPT` at most."""
    lss = network.lss

    def on_answer(can_id: int, data: bytearray, timestamp: float) -> None:
        if lss.responses.qsize() < RESPONSES_KEPT:
            lss.responses.put(bytes(data))

    if lss.on_message_received in network.subscribers.get(lss.LSS_RX_COBID, []):
        network.unsubscribe(lss.LSS_RX_COBID, lss.on_message_received)
        network.subscribe(lss.LSS_RX_COBID, on_answer)


def log_unknown(unknown: UnknownNode) -> None:
    """The one log line of a node the host does not manage."""
    logger.warning("node %d: %s; left alone", unknown.node_id, unknown.reason,
                   extra={"unknown_node": unknown})


class HaltableSdoClient(SdoClient):
    """canopen's SDO client, that :meth:`halt` ends at once: the transfer waiting for a
    response raises, and so does every request after it (a host stops within a heartbeat
    period, not after an SDO time-out per request left in a set-up)."""

    HALTED = b"halted"

    def __init__(self, rx_cobid: int, tx_cobid: int, od: canopen.ObjectDictionary) -> None:
        super().__init__(rx_cobid, tx_cobid, od)
        self.halted = threading.Event()
        self.dropped = 0  # responses nobody was waiting for, beyond what is kept

    def on_response(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """canopen queues every response, asked for or not: a flood of them between
        transfers would grow without bound. Keep :data:`RESPONSES_KEPT` at most."""
        if self.responses.qsize() >= RESPONSES_KEPT:
            self.dropped += 1
            return
        self.responses.put(bytes(data))

    def halt(self) -> None:
        self.halted.set()
        self.responses.put(self.HALTED)

    def resume(self) -> None:
        """Take requests again (the host starts again)."""
        self.halted.clear()

    def send_request(self, request: bytes | bytearray) -> None:
        if self.halted.is_set():
            raise SdoCommunicationError("halted: the host is stopping")
        super().send_request(request)

    def read_response(self) -> bytes:
        try:
            response = self.responses.get(block=True, timeout=self.RESPONSE_TIMEOUT)
        except queue.Empty:
            raise SdoCommunicationError("No SDO response received") from None
        if response is self.HALTED:
            raise SdoCommunicationError("halted: the host is stopping")
        if len(response) != SDO_FRAME:  # canopen would fail on it with a struct.error
            raise SdoCommunicationError(f"malformed SDO response ({len(response)} bytes: "
                                        f"{bytes(response).hex()})")
        if response[0] == RESPONSE_ABORTED:
            raise SdoAbortedError(int.from_bytes(response[4:8], "little"))
        return bytes(response)


def haltable_sdo(node: canopen.RemoteNode) -> HaltableSdoClient:
    """Give ``node`` (not yet on a network) a :class:`HaltableSdoClient`; returns it."""
    node_id = int(node.id or 0)
    client = HaltableSdoClient(0x600 + node_id, 0x580 + node_id, node.object_dictionary)
    node.sdo = client
    node.sdo_channels = [client]
    return client


def read_identity(sdo: SdoClient) -> Identity:
    """Read 0x1018 sub-indexes 1..4 (raises canopen's SDO errors)."""
    values = [struct.unpack("<I", sdo.upload(0x1018, s).ljust(4, b"\x00")[:4])[0]
              for s in range(1, 5)]
    return Identity(*values)


@contextmanager
def sdo_client(network: canopen.Network, node_id: int, *,
               timeout_s: float) -> Iterator[HaltableSdoClient]:
    """An SDO client for ``node_id`` subscribed to ``network`` for the ``with`` block.

    Only for nodes the host has no :class:`canopen.RemoteNode` for: two clients on one
    server would both take every response.
    """
    client = HaltableSdoClient(0x600 + node_id, 0x580 + node_id, canopen.ObjectDictionary())
    client.RESPONSE_TIMEOUT = timeout_s
    client.network = network
    network.subscribe(client.tx_cobid, client.on_response)
    try:
        yield client
    finally:
        network.unsubscribe(client.tx_cobid, client.on_response)


def scan(network: canopen.Network, wait_s: float, *, exclude: Iterable[int] = (),
         halt: threading.Event | None = None) -> list[int]:
    """Node-IDs that answer canopen's SDO scan (an upload of 0x1000 to every node-ID)
    within ``wait_s`` (or until ``halt`` is set), or that the scanner saw otherwise
    (heartbeat, EMCY, TPDO)."""
    network.scanner.reset()
    network.scanner.search()
    (halt or threading.Event()).wait(wait_s)
    skip = set(exclude)
    return sorted(n for n in network.scanner.nodes if n not in skip)


class BootListener:
    """Calls ``on_boot(node_id)`` for every boot-up message (0x700 + ID, one byte 0x00)."""

    def __init__(self, network: canopen.Network, on_boot: Callable[[int], None]) -> None:
        self.network = network
        self.on_boot = on_boot
        self._ids = [_HEARTBEAT + node for node in fields.NODE_IDS]

    def start(self) -> None:
        for cob_id in self._ids:
            self.network.subscribe(cob_id, self._on_message)

    def stop(self) -> None:
        for cob_id in self._ids:
            if self._on_message in self.network.subscribers.get(cob_id, []):
                self.network.unsubscribe(cob_id, self._on_message)

    def _on_message(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if len(data) == 1 and data[0] == BOOTUP:
            self.on_boot(can_id - _HEARTBEAT)
