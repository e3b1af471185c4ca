"""LSS slave (CiA 305): a device found by its identity and given a node-ID and bit timing.

Requests come on 0x7E5, answers go on 0x7E4 (8 bytes, the command specifier first).
Switch state selective answers once all four parts matched, identify remote slave from
every device inside the ranges (vendor, product, revision low/high, serial low/high):

| cs | service | state | answer |
|---|---|---|---|
| 0x04 | switch state global (byte 1: 0 waiting, 1 configuration) | any | none |
| 0x40..0x43 | switch state selective: vendor, product, revision, serial | waiting | 0x44 |
| 0x11 | configure node-ID (1..127, 0xFF) | configuration | 0x11, error 0 or 1 |
| 0x13 | configure bit timing (table 0, index 0..9 but 5) | configuration | 0x13, error 0 or 1 |
| 0x15 | activate bit timing (switch delay in ms) | configuration | none |
| 0x17 | store configuration (node-ID, bit timing) | configuration | 0x17, error 0 or 2 |
| 0x46..0x4B | identify remote slave: vendor, product, revision, serial ranges | any | 0x4F |
| 0x4C | identify non-configured remote slave | any | 0x50 from each device with node-ID 0xFF |
| 0x51 | fastscan | waiting, node-ID 0xFF | 0x4F, see :meth:`LssSlave._fastscan` |
| 0x5A..0x5E | inquire vendor, product, revision, serial, node-ID | configuration | cs, value |

A device whose node-ID is 0xFF leaves the configuration state for the waiting state with
the node-ID configured: it boots with it at once. A configured device keeps its node-ID
until its next NMT reset. CiA 305 has no inquiry of the bit timing; a simulated bus has no
bit rate to switch, so activation only makes the configured bit timing the active one.
"""

from __future__ import annotations

import logging
import struct
import threading
from typing import Protocol

import canopen

from canbus.device.nv_store import BIT_TIMINGS, NvStore
from canbus.identity import Identity
from skin.inputs.fields import UNCONFIGURED, is_node_id

logger = logging.getLogger(__name__)

LSS_MASTER, LSS_SLAVE = 0x7E5, 0x7E4
WAITING, CONFIGURATION = 0, 1
SWITCH_GLOBAL, SELECTIVE_ANSWER = 0x04, 0x44
SELECTIVE = range(0x40, 0x44)
CONFIGURE_NODE_ID, CONFIGURE_BIT_TIMING, ACTIVATE_BIT_TIMING, STORE = 0x11, 0x13, 0x15, 0x17
IDENTIFY = range(0x46, 0x4C)
IDENTIFY_NON_CONFIGURED, IDENTIFY_ANSWER, NON_CONFIGURED_ANSWER = 0x4C, 0x4F, 0x50
FASTSCAN, FASTSCAN_CONFIRM = 0x51, 0x80
INQUIRE = range(0x5A, 0x5F)
INQUIRE_NODE_ID = 0x5E
ERROR_NONE, ERROR_INADMISSIBLE, ERROR_STORAGE = 0, 1, 2


class LssDevice(Protocol):
    """What LSS needs of a device (``canbus.device.local_device.LocalDevice``)."""

    node_id: int
    identity: Identity
    nv: NvStore

    def adopt_node_id(self, node_id: int) -> None: ...


class LssSlave:
    """The LSS side of ``device`` (its identity is its 0x1018 sub 1..4)."""

    def __init__(self, device: LssDevice) -> None:
        self.device = device
        self.state = WAITING
        self.pending_node_id = device.node_id
        self.bit_timing = device.nv.content.bit_timing
        """The active bit timing (CiA 305 table 0 index; None: as the device was built)."""
        self.pending_bit_timing = self.bit_timing
        self.network: canopen.Network | None = None
        self._selective: list[int] = []  # the identity parts matched so far, in order
        self._identify: list[int] = []  # the remote-slave request values so far
        self._fastscan_at: int | None = None  # the LSS sub the next fastscan step checks
        self._adopting = False
        self._lock = threading.RLock()

    @property
    def address(self) -> tuple[int, int, int, int]:
        """Vendor-ID, product code, revision number, serial number."""
        i = self.device.identity
        return (i.vendor, i.product, i.revision, i.serial)

    def attach(self, network: canopen.Network) -> None:
        self.network = network
        network.subscribe(LSS_MASTER, self.on_request)

    def detach(self) -> None:
        if self.network is not None:
            self.network.unsubscribe(LSS_MASTER, self.on_request)
            self.network = None

    def on_request(self, can_id: int, data: bytearray | bytes, timestamp: float) -> None:
        """One frame on 0x7E5; a frame that is not an LSS request (not 8 bytes, an unknown
        command specifier) is ignored, as CiA 305 asks."""
        if len(data) != 8:
            logger.info("ignored LSS frame of %d bytes", len(data))
            return
        with self._lock:  # not the device's: a node-ID being taken must not hold up LSS
            self._dispatch(bytes(data))

    def _dispatch(self, data: bytes) -> None:
        cs = data[0]
        value = struct.unpack_from("<I", data, 1)[0]
        if cs == SWITCH_GLOBAL:
            self._switch_global(data[1])
        elif cs in SELECTIVE:
            self._switch_selective(cs - SELECTIVE.start, value)
        elif cs in IDENTIFY:
            self._identify_step(cs - IDENTIFY.start, value)
        elif cs == IDENTIFY_NON_CONFIGURED:
            if self.device.node_id == UNCONFIGURED and self.pending_node_id == UNCONFIGURED:
                self._answer(NON_CONFIGURED_ANSWER)
        elif cs == FASTSCAN:
            self._fastscan(value, data[5], data[6], data[7])
        elif self.state != CONFIGURATION:
            return  # the remaining services are for a device in configuration state
        elif cs == CONFIGURE_NODE_ID:
            self._configure_node_id(data[1])
        elif cs == CONFIGURE_BIT_TIMING:
            self._configure_bit_timing(data[1], data[2])
        elif cs == ACTIVATE_BIT_TIMING:
            self.bit_timing = self.pending_bit_timing
            logger.info("LSS: bit timing %s active (after %d ms)", self.bit_timing,
                        struct.unpack_from("<H", data, 1)[0])
        elif cs == STORE:
            self._store()
        elif cs in INQUIRE:
            self._inquire(cs)

    def _answer(self, cs: int, payload: bytes = b"") -> None:
        if self.network is not None:
            self.network.send_message(LSS_SLAVE, bytes([cs]) + payload.ljust(7, b"\0"))

    def _switch_global(self, mode: int) -> None:
        if mode == CONFIGURATION:
            self.state = CONFIGURATION
        elif mode == WAITING:
            self._to_waiting()

    def _to_waiting(self) -> None:
        self.state = WAITING
        self._selective.clear()
        unconfigured = self.device.node_id == UNCONFIGURED
        if unconfigured and self.pending_node_id != UNCONFIGURED and not self._adopting:
            # Building the object store anew takes a while (the EDS is read for the new
            # node-ID): not on the network's thread, where the other patches' LSS answers
            # would wait for it. Meanwhile the pending node-ID keeps the device out of
            # fastscan and the non-configured identification.
            self._adopting = True
            threading.Thread(target=self._adopt, args=(self.pending_node_id,), daemon=True,
                             name=f"lss-node-{self.pending_node_id}").start()

    def _adopt(self, node_id: int) -> None:
        try:
            self.device.adopt_node_id(node_id)
        finally:
            self._adopting = False

    def _switch_selective(self, part: int, value: int) -> None:
        if self.state != WAITING:
            return
        if part == 0:
            self._selective = []
        if part != len(self._selective) or value != self.address[part]:
            self._selective = []
            return
        self._selective.append(value)
        if len(self._selective) == 4:
            self._selective = []
            self.state = CONFIGURATION
            self._answer(SELECTIVE_ANSWER)

    def _identify_step(self, step: int, value: int) -> None:
        if step == 0:
            self._identify = []
        if step != len(self._identify):
            self._identify = []
            return
        self._identify.append(value)
        if len(self._identify) < 6:
            return
        vendor, product, rev_low, rev_high, serial_low, serial_high = self._identify
        self._identify = []
        v, p, r, s = self.address
        if v == vendor and p == product and rev_low <= r <= rev_high and \
                serial_low <= s <= serial_high:
            self._answer(IDENTIFY_ANSWER)

    def _fastscan(self, id_number: int, bit_check: int, sub: int, nxt: int) -> None:
        """CiA 305 fastscan: a device with node-ID 0xFF in waiting state answers the
        confirmation (bit check 0x80), then every step whose ID bits 31..bit_check of LSS
        sub ``sub`` match its own; the last step (bit 0 of the serial, next 0) puts the
        one device so identified into configuration state."""
        if self.device.node_id != UNCONFIGURED or self.pending_node_id != UNCONFIGURED or \
                self.state != WAITING:
            return
        if not (bit_check <= 31 or bit_check == FASTSCAN_CONFIRM) or sub > 3 or nxt > 3:
            return
        if bit_check == FASTSCAN_CONFIRM:
            self._fastscan_at = 0
            self._answer(IDENTIFY_ANSWER)
            return
        if self._fastscan_at != sub:
            return
        mask = (0xFFFF_FFFF << bit_check) & 0xFFFF_FFFF
        if (self.address[sub] ^ id_number) & mask:
            return
        self._fastscan_at = nxt
        if bit_check == 0 and nxt < sub:
            self.state = CONFIGURATION
            self._fastscan_at = None
        self._answer(IDENTIFY_ANSWER)

    def _configure_node_id(self, node_id: int) -> None:
        if is_node_id(node_id) or node_id == UNCONFIGURED:
            self.pending_node_id = node_id
            self._answer(CONFIGURE_NODE_ID, bytes([ERROR_NONE]))
        else:
            self._answer(CONFIGURE_NODE_ID, bytes([ERROR_INADMISSIBLE]))

    def _configure_bit_timing(self, table: int, index: int) -> None:
        if table == 0 and index in BIT_TIMINGS and index != 5:
            self.pending_bit_timing = index
            self._answer(CONFIGURE_BIT_TIMING, bytes([ERROR_NONE]))
        else:
            self._answer(CONFIGURE_BIT_TIMING, bytes([ERROR_INADMISSIBLE]))

    def _store(self) -> None:
        try:
            self.device.nv.save_lss(self.pending_node_id, self.pending_bit_timing)
        except OSError as err:
            logger.warning("LSS store configuration failed: %s", err)
            self._answer(STORE, bytes([ERROR_STORAGE]))
        else:
            self._answer(STORE, bytes([ERROR_NONE]))

    def _inquire(self, cs: int) -> None:
        if cs == INQUIRE_NODE_ID:
            self._answer(cs, bytes([self.device.node_id]))
        else:
            self._answer(cs, struct.pack("<I", self.address[cs - INQUIRE.start]))
