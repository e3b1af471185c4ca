"""What is on a bus, by identity: configured nodes by SDO (0x1018), unconfigured ones by LSS.

A configured node answers canopen's SDO scan and its identity is read from 0x1018. A node
waiting for LSS (node-ID 0xFF) answers only LSS; canopen's ``LssMaster.fast_scan`` finds
the smallest identity among them and puts that node into configuration state, which is
the step before giving it a node-ID, not a way to list them. :func:`unconfigured` lists
them all and changes nothing: it walks the CiA 305 fastscan tree depth-first, with every
step's "next LSS sub" left on the sub being checked, so no node ever reaches the
configuration state; a branch nobody answers costs one time-out. By default it looks for
canskin patches (vendor, product and revision of the shipped EDS, each confirmed by one
step) and walks the 32 bits of their serial numbers; ``thorough`` walks all 128 bits.

Every waiting node answers a step it matches, with the same frame, so one step's answers
cannot be told from the next one's: an answer that arrives after the step that asked for
it (on udp_multicast the simulated patches answer one after the other, from another
process) would pass for a match of the next step and invent a node. A step that was
answered therefore takes its answers until the bus is quiet for ``SETTLE_S``, and every
identity the walk ends on is confirmed after a whole time-out of quiet by the one exchange
whose answers carry the identity (:meth:`Fastscan.present`: switch state selective, LSS
inquire, back to waiting): a node is listed only if it tells its own identity back.
"""

from __future__ import annotations

import queue
import struct
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import canopen
from canopen.sdo.exceptions import SdoError

from canbus.device.local_device import eds_identity
from canbus.device.lss_slave import (
    FASTSCAN,
    FASTSCAN_CONFIRM,
    IDENTIFY_ANSWER,
    INQUIRE,
    LSS_MASTER,
    SELECTIVE,
    SWITCH_GLOBAL,
    WAITING,
)
from canbus.identity import Identity
from canbus.master.discovery import read_identity, scan, sdo_client

DEFAULT_TIMEOUT_S = 0.1
SETTLE_S = 0.02
"""The quiet that ends an answered step: every node answers a step at once."""


@dataclass(frozen=True)
class FoundNode:
    """One node on the bus: its identity and node-ID (None: waiting for LSS)."""

    identity: Identity
    node_id: int | None

    @property
    def configured(self) -> bool:
        return self.node_id is not None

    def as_dict(self) -> dict[str, object]:
        i = self.identity
        return {"node_id": self.node_id, "configured": self.configured, "vendor": i.vendor,
                "product": i.product, "revision": i.revision, "serial": i.serial,
                "kind": i.kind}


class Fastscan:
    """CiA 305 fastscan steps on ``network`` (answers on 0x7E4)."""

    def __init__(self, network: canopen.Network, timeout_s: float = DEFAULT_TIMEOUT_S) -> None:
        self.network = network
        self.timeout_s = timeout_s
        self.steps = 0
        self._answers: queue.Queue[bytes] = queue.Queue()

    @contextmanager
    def listening(self) -> Iterator[Fastscan]:
        self.network.subscribe(0x7E4, self._on_answer)
        try:
            yield self
        finally:
            self.network.unsubscribe(0x7E4, self._on_answer)

    def _on_answer(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self._answers.put(bytes(data))

    def step(self, id_number: int, bit_check: int, sub: int, nxt: int) -> bool:
        """One fastscan request; True if any node answered."""
        self._quiet(0.0)  # a late answer to an earlier step
        self.steps += 1
        self.network.send_message(LSS_MASTER, struct.pack("<BIBBB", FASTSCAN, id_number,
                                                          bit_check, sub, nxt))
        if not self._answered():
            return False
        self._quiet(min(SETTLE_S, self.timeout_s))  # the other nodes' answers to this step
        return True

    def present(self, identity: Identity) -> bool:
        """Whether a node has exactly ``identity``: after a time-out of quiet, LSS switch
        state selective to it, then LSS inquire of each part of its identity, then every
        node back to waiting. Only that node enters the configuration state, and only a node
        in it answers an inquiry, with the value it holds: no late or repeated answer to a
        fastscan step or identify request (cs 0x4F), nor another node's inquiry answer, can
        pass for it. Nothing is configured on the way."""
        self._quiet(self.timeout_s)
        parts = (identity.vendor, identity.product, identity.revision, identity.serial)
        for k, value in enumerate(parts):
            self.network.send_message(LSS_MASTER, struct.pack("<BI3x", SELECTIVE.start + k,
                                                              value))
        try:
            return all(self._told(INQUIRE.start + k, value) for k, value in enumerate(parts))
        finally:
            self.network.send_message(LSS_MASTER, struct.pack("<BB6x", SWITCH_GLOBAL, WAITING))

    def _told(self, cs: int, value: int) -> bool:
        """LSS inquire ``cs``: True if ``value`` comes back within the time-out."""
        self.network.send_message(LSS_MASTER, struct.pack("<B7x", cs))
        want = struct.pack("<BI", cs, value)
        try:
            while True:
                if self._answers.get(timeout=self.timeout_s)[:5] == want:
                    return True
        except queue.Empty:
            return False

    def _answered(self) -> bool:
        """An answer within the time-out (other frames on 0x7E4 are skipped)."""
        try:
            while True:
                answer = self._answers.get(timeout=self.timeout_s)
                if answer and answer[0] == IDENTIFY_ANSWER:
                    return True
        except queue.Empty:
            return False

    def _quiet(self, gap_s: float) -> None:
        """Take every answer until none has come for ``gap_s`` (0: those already here)."""
        try:
            while True:
                if gap_s > 0:
                    self._answers.get(timeout=gap_s)
                else:
                    self._answers.get_nowait()
        except queue.Empty:
            return

    def reset(self) -> bool:
        """The confirmation step: every unconfigured node back to LSS sub 0; True if any."""
        return self.step(0, FASTSCAN_CONFIRM, 0, 0)

    def walk_to(self, prefix: list[int]) -> bool:
        """Move the nodes whose subs 0..k-1 are ``prefix`` to sub k (the others stay)."""
        if not self.reset():
            return False
        return all(self.step(value, 0, sub, sub + 1) for sub, value in enumerate(prefix))

    def values(self, sub: int) -> list[int]:
        """Every value of LSS sub ``sub`` among the nodes at that sub, depth-first."""
        found: list[int] = []

        def walk(value: int, bit: int) -> None:
            for b in (0, 1):
                v = value | (b << bit)
                if self.step(v, bit, sub, sub):
                    if bit == 0:
                        found.append(v)
                    else:
                        walk(v, bit - 1)

        walk(0, 31)
        return found


def unconfigured(network: canopen.Network, *, timeout_s: float = DEFAULT_TIMEOUT_S,
                 thorough: bool = False) -> list[Identity]:
    """The identities of every node waiting for LSS (node-ID 0xFF), in ascending order."""
    scan_ = Fastscan(network, timeout_s)
    out: list[Identity] = []
    with scan_.listening():
        if not scan_.reset():
            return out

        def branch(prefix: list[int]) -> None:
            sub = len(prefix)
            if sub == 4:
                if scan_.present(Identity(*prefix)):
                    out.append(Identity(*prefix))
                return
            if sub and not scan_.walk_to(prefix):
                return
            if not thorough and sub < 3:
                known = eds_identity("skin-patch")[sub]
                candidates = [known] if scan_.step(known, 0, sub, sub) else []
            else:
                candidates = scan_.values(sub)
            for value in candidates:
                branch([*prefix, value])

        branch([])
    return out


def configured(network: canopen.Network, *, scan_s: float = 0.3,
               sdo_timeout_s: float = 0.5) -> list[FoundNode]:
    """Every node that answers SDO, with its identity (0x1018)."""
    out = []
    for node_id in scan(network, scan_s):
        with sdo_client(network, node_id, timeout_s=sdo_timeout_s) as sdo:
            try:
                identity = read_identity(sdo)
            except (SdoError, struct.error):
                identity = Identity(0, 0, 0, 0)
        out.append(FoundNode(identity, node_id))
    return out


def lss_scan(network: canopen.Network, *, timeout_s: float = DEFAULT_TIMEOUT_S,
             thorough: bool = False, scan_s: float = 0.3) -> list[FoundNode]:
    """Configured nodes (by node-ID), then the nodes waiting for LSS (by identity)."""
    waiting = unconfigured(network, timeout_s=timeout_s, thorough=thorough)
    return configured(network, scan_s=scan_s) + [FoundNode(i, None) for i in waiting]
