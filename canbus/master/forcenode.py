# canopen 2.4 ships py.typed but leaves LocalNode/SdoServer methods unannotated.
# mypy: disable-error-code="no-untyped-call"
"""The force node: one patch's decoded forces as a CANopen device (eds/skin-forces.eds).

Objects: 0x2000 forces, 27 INTEGER16 in mN (taxel*3 + axis + 1; Fx, Fy, Fz); 0x2001 the
source patch's node-ID; 0x2004 per-taxel status (the ``decoder.reasons`` code, 0 OK);
0x2005 valid taxels, UNSIGNED16 (bit k = taxel k valid, bit 15 = sample complete); 0x2006
the counter byte of the SYNC the sample answers (0: none); 0x2007 tare: writing 1 by SDO
re-zeroes the source patch at its last sample (aborted with 0x08000022 while the patch is
loaded or not decoded, 0x06090030 for any other value). A taxel that is invalid, or
has a component that does not fit INTEGER16 (never clipped), has its valid bit cleared
and all three components sent as 0x8000 (-32768, "no value").

0x2008 the patch's contact summary and 0x2009 the thresholds it is judged by
(:mod:`canbus.contact_record`; the node's :class:`~canbus.master.contact.PatchContact`).

The default mapping is 4 forces per TPDO, TPDO 7 = the last 3 forces + 0x2005, TPDO 8 the
contact (net Fz, CoP x, y, state, taxels in contact), all event-driven (type 254):
:meth:`ForceNode.frames` returns the frames of one sample, sent as soon as it is decoded.
On a CAN FD bus :func:`map_fd` puts a whole sample in TPDO 1 (27 forces, 0x2005, 0x2006,
and the contact's net Fz, CoP and state: 64 bytes, one frame, CiA 1301). The node answers
SDO, sends its boot-up and heartbeat and obeys NMT like a patch node; it transmits only
while OPERATIONAL (:attr:`transmitting`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numpy as np
from canopen.sdo.exceptions import SdoAbortedError
from numpy.typing import ArrayLike, NDArray

from canbus import contact_record
from canbus.device.local_device import LocalDevice
from canbus.device.nmt_slave import OPERATIONAL, START
from canbus.device.nv_store import NvStore
from canbus.mappings import force_fd_entries
from canbus.master.contact import ContactSummarizer, PatchContact
from canbus.master.forceframes import (
    ANSWERED,
    FORCES,
    NO_VALUE,
    STATUS,
    VALID,
    Frame,
    FrameBatcher,
)
from canbus.od import load_od
from canbus.pdo_codec import (
    COB_ID_INVALID,
    TPDO_COMM,
    TPDO_MAP,
    MappedEntry,
    PdoCodec,
    read_defaults,
    read_layouts,
)
from skin.contact_state import ContactBatch
from skin.errors import BusError, SkinError
from skin.inputs import fields

SOURCE, TARE = 0x2001, 0x2007
CONTACT, CONTACT_PARAMS = contact_record.CONTACT, contact_record.CONTACT_PARAMS
TPDO_COUNT = 8
"""The force node's TPDOs: 1..7 the forces, 8 the contact."""
CONTACT_TPDO = 8
TARE_COMMAND = 1
"""Written to 0x2007 by any master: re-zero the source patch at its last sample."""
DEVICE_STATE = 0x0800_0022
"""SDO abort: the data cannot be stored because of the present device state (CiA 301)."""
INVALID_VALUE = 0x0609_0030
logger = logging.getLogger(__name__)

FD_MAPPING: tuple[MappedEntry, ...] = force_fd_entries()
"""A whole sample in one CAN FD TPDO: 27 forces, 0x2005, 0x2006, and the contact's net Fz,
CoP x, y and state (64 bytes; without a contact summary its state says ``unknown``)."""


def map_fd(node: ForceNode) -> None:
    """Map the node's TPDO 1 to :data:`FD_MAPPING` and invalidate TPDO 2..8, with CiA 301's
    sequence (invalidate, sub-index 0 = 0, entries, count, validate), as a master would by
    SDO. The node must be on a CAN FD bus (its PDOs may hold 64 bytes)."""
    mapping = FD_MAPPING
    with node.lock:
        store = node.store
        for n in range(TPDO_COUNT):
            cob = int(store.value(TPDO_COMM + n, 1))
            store.set_data(TPDO_COMM + n, 1, (cob | COB_ID_INVALID).to_bytes(4, "little"))
        store.set_data(TPDO_MAP, 0, b"\x00")
        for s, entry in enumerate(mapping, start=1):
            store.set_data(TPDO_MAP, s, entry.to_raw().to_bytes(4, "little"))
        store.set_data(TPDO_MAP, 0, bytes([len(mapping)]))
        cob = int(store.value(TPDO_COMM, 1))
        store.set_data(TPDO_COMM, 1, (cob & ~COB_ID_INVALID).to_bytes(4, "little"))


def force_node_cob_ids(node_id: int) -> frozenset[int]:
    """Every COB-ID a force node at ``node_id`` transmits on by default (EDS values).

    TPDOs, EMCY, heartbeat (also boot-up) and SDO server-to-client: what a configuration
    check compares against the patches' identifiers without building a node.
    """
    od = load_od("skin-forces", node_id)
    read = read_defaults(od)
    tpdos = {layout.cob_id for layout in read_layouts(read, TPDO_COUNT)}
    return frozenset(tpdos | {read(0x1014, 0) & 0x7FF, 0x700 + node_id, read(0x1200, 2) & 0x7FF})


class ForceNode(LocalDevice):
    """The force node of patch ``source_patch`` at node-ID ``node_id`` (1..127).

    ``contact``: the patch's contact judge (True: one with default geometry and
    thresholds; None or False: no contact summary, TPDO 8 invalid from power-on)."""

    NOT_STORED = frozenset({TARE})
    _last_contact: tuple[ContactBatch, int] | None

    def __init__(self, node_id: int, source_patch: int, *, heartbeat_ms: int = 1000,
                 contact: PatchContact | bool | None = True, nv: NvStore | None = None) -> None:
        fields.node_id(source_patch, "source_patch")
        fields.integer(heartbeat_ms, "heartbeat_ms", 0, 0xFFFF)
        self.source_patch = source_patch
        self.heartbeat_ms = heartbeat_ms
        self.on_tare: Callable[[], None] | None = None
        """Called when a master writes 1 to 0x2007 (on the SDO server's thread); an
        exception refuses the write: :class:`SkinError` with abort 0x08000022."""
        self.contact: PatchContact | None = (
            PatchContact() if contact is True else
            contact if isinstance(contact, PatchContact) else None)
        """The patch's contact judge (None: no contact summary)."""
        self._summarizer = ContactSummarizer()
        self._batcher = FrameBatcher()
        self._clear_application()
        super().__init__(node_id, "skin-forces", TPDO_COUNT, serial=node_id, nv=nv)

    def _on_store_built(self) -> None:
        self.store.validators.append(self._tare)

    @property
    def codec(self) -> PdoCodec:
        """The force TPDOs as currently mapped (another master may remap them by SDO)."""
        with self.lock:
            return self.tpdo.codec

    @property
    def transmitting(self) -> bool:
        """OPERATIONAL: the node's PDOs may go onto the bus."""
        return self.nmt.state == OPERATIONAL

    def start(self) -> None:
        """Enter OPERATIONAL, as an NMT start from a master would (the host's own nodes)."""
        if self.network is None:
            raise BusError(f"force node {self.node_id} must be attached before it starts")
        with self.lock:
            self.nmt.on_command(0, bytes([START, self.node_id]), 0.0)

    def cob_ids(self) -> frozenset[int]:
        """Every COB-ID the node transmits on now: TPDOs, EMCY, heartbeat, SDO responses."""
        with self.lock:
            tpdos = {int(c) for c in self.tpdo.codec.cob_ids}
            emcy = int(self.store.value(0x1014)) & 0x7FF
            sdo_tx = int(self.store.value(0x1200, 2)) & 0x7FF
        return frozenset(tpdos | {emcy, 0x700 + self.node_id, sdo_tx})

    def frames(self, force_N: ArrayLike, valid: ArrayLike, complete: bool, *,
               reason: ArrayLike | None = None, answered: int = 0) -> list[Frame]:
        """The TPDO frames of one sample: ``(9, 3)`` N, ``(9,)`` valid, the complete flag.

        Also the values an SDO read of 0x2000, 0x2004 and 0x2005 returns from now on.
        ``reason`` (9,) is the ``decoder.reasons`` code per taxel for 0x2004; without it an
        invalid taxel reads ``UNSPECIFIED``. The frames are returned whatever the NMT state:
        the sender checks :attr:`transmitting`.
        """
        f = np.asarray(force_N, dtype=np.float64).reshape(1, 9, 3)
        v = np.asarray(valid, dtype=bool).reshape(1, 9)
        r = None if reason is None else np.asarray(reason, dtype=np.uint8).reshape(1, 9)
        contact = None
        if self.contact is not None:
            contact = self._summarizer.batch([self.contact], f, v, decoded=False)
        return self._batcher.frames([self], f, v, np.array([complete]), r, answered,
                                    contact)[0]

    def adopt(self, forces_mN: NDArray[np.int16], status: NDArray[np.uint8],
               valid: int, answered: int, contact: ContactBatch | None = None,
               row: int = 0) -> PdoCodec:
        """Take one sample's object values; the codec to pack them with."""
        with self.lock:
            self._forces_mN = forces_mN
            self._status = status
            self._valid = valid
            self._answered = answered
            self._last_contact = None if contact is None or self.contact is None \
                else (contact, row)
            return self.tpdo.codec

    def _read_live(self, index: int, subindex: int, **_: Any) -> int | None:
        if index == FORCES and subindex:
            return int(self._forces_mN[subindex - 1])
        if index == STATUS and subindex:
            return int(self._status[subindex - 1])
        if index == VALID:
            return self._valid
        if index == ANSWERED:
            return self._answered
        if index == CONTACT and 1 <= subindex <= contact_record.SUBS:
            if self._last_contact is None:
                return int(contact_record.no_summary([subindex], 1)[0, 0])
            batch, row = self._last_contact
            return int(contact_record.encode(batch, [subindex])[row, 0])
        return None

    def _tare(self, index: int, subindex: int, value: Any) -> None:
        if index != TARE:
            return
        if value != TARE_COMMAND:
            raise SdoAbortedError(INVALID_VALUE)
        if self.on_tare is None:
            raise SdoAbortedError(DEVICE_STATE)
        try:
            self.on_tare()
        except SkinError as err:
            logger.warning("force node %d: tare of patch %d refused: %s", self.node_id,
                           self.source_patch, err)
            raise SdoAbortedError(DEVICE_STATE) from err

    def clear_sample(self) -> None:
        """Forget the last sample: every force reads 0x8000 again, no taxel valid."""
        with self.lock:
            self._clear_application()

    def _clear_application(self) -> None:
        """No sample published yet: every force reads 0x8000, no taxel valid."""
        self._forces_mN = np.full(27, NO_VALUE, dtype=np.int16)
        self._status = np.zeros(9, dtype=np.uint8)
        self._valid = 0
        self._answered = 0
        self._last_contact = None

    def _apply_defaults(self) -> None:
        """Power-on values the EDS cannot know: source patch, heartbeat period, the contact
        thresholds (without a contact summary: TPDO 8 invalid)."""
        self.store.store(SOURCE, 0, self.source_patch)
        self.store.store(0x1017, 0, self.heartbeat_ms)
        if self.contact is None:
            index = TPDO_COMM + CONTACT_TPDO - 1
            self.store.store(index, 1, int(self.store.value(index, 1)) | COB_ID_INVALID)
        else:
            self.contact.reset()
            for sub, value in enumerate(contact_record.param_values(self.contact.params), 1):
                self.store.store(CONTACT_PARAMS, sub, value)
        self.tpdo.reset()
