"""What a recording shows about its patches: their TPDO mapping, heartbeat, LSB and R0, and
its SYNC, read once through the file before it is decoded.

A patch's mapping is the one its EDS gives (``skin-patch.eds``) with every SDO value a
master wrote to it (a confirmed download) or read from it applied, as the sniffer follows
them (:class:`~canbus.tools.pdo_names.NodeView`): the mapping in force when the patch's
first PDO crosses the bus. A mapping that changes after that, while the patch sends PDOs,
is recorded as a remap (the caller refuses it: one recording, one mapping per patch).
"""

from __future__ import annotations

import itertools
import os
import statistics
from dataclasses import dataclass, field

import can

from canbus.patch_constants import decode_si
from canbus.pdo_codec import TpdoLayout
from canbus.tools.pdo_dictionary import Dictionary
from canbus.tools.pdo_names import NodeView
from canbus.tools.recording import Recording
from canbus.tools.services import SdoDecoder

SYNC_COB_ID = 0x080
HEARTBEAT, SDO_TX, SDO_RX = 0x700, 0x580, 0x600
HEARTBEAT_TIME, LSB, NOMINAL = 0x1017, 0x2001, 0x2002
PDO_PARAMETERS = range(0x1800, 0x1C00)


@dataclass
class PatchFacts:
    """One patch as the recording shows it."""

    node_id: int
    layouts: tuple[TpdoLayout, ...] = ()
    """The TPDO mapping in force at its first PDO (the EDS default and the SDO values)."""
    first_pdo_frame: int | None = None  # 1-based frame number in the recording
    mapping_from_sdo: bool = False  # an SDO transfer showed a PDO parameter before it
    remapped_frame: int | None = None  # a PDO sent under another mapping than the first
    pdo_frames: int = 0
    wrong_length_frames: int = 0  # PDOs whose length is not their mapping's
    fd_frames: int = 0
    heartbeat_ms_written: int | None = None  # the last 0x1017 a master wrote
    heartbeat_times: list[float] = field(default_factory=list)
    lsb_ohm: float | None = None  # 0x2001 as read or written by SDO
    r0_ohm: dict[int, float] = field(default_factory=dict)  # 0x2002 sub -> value seen

    @property
    def heartbeat_ms_measured(self) -> float | None:
        """The median interval between its heartbeats (None for fewer than 3)."""
        times = self.heartbeat_times
        if len(times) < 3:
            return None
        return 1000.0 * statistics.median(b - a for a, b in itertools.pairwise(times))


@dataclass
class RecordingFacts:
    """What :func:`scan_recording` found."""

    source: str
    frames: int = 0
    sync_times: list[float] = field(default_factory=list)
    sync_counters: int = 0  # SYNCs that carried a counter byte
    patches: dict[int, PatchFacts] = field(default_factory=dict)

    @property
    def sync_period_s(self) -> float | None:
        """The median SYNC interval (None for fewer than 2 SYNCs)."""
        t = self.sync_times
        if len(t) < 2:
            return None
        return statistics.median(b - a for a, b in itertools.pairwise(t))


def _tpdos(view: NodeView) -> tuple[TpdoLayout, ...]:
    return tuple(sorted((e.layout for e in view.pdos.values() if e.kind == "TPDO"),
                        key=lambda layout: layout.number))


def scan_recording(path: str | os.PathLike[str], node_ids: tuple[int, ...]) -> RecordingFacts:
    """Read the recording once; raises :class:`~skin.errors.RecordingError` naming the first
    damaged frame."""
    facts = RecordingFacts(os.fspath(path))
    dictionary = Dictionary()
    views = {n: dictionary.view(n) for n in node_ids}
    sdo = SdoDecoder()
    patches = {n: PatchFacts(n) for n in node_ids}
    facts.patches = patches
    pdo_owner: dict[int, int] = {}  # TPDO COB-ID -> node, under each node's current mapping

    def refresh(node: int) -> None:
        for cob in [c for c, n in pdo_owner.items() if n == node]:
            del pdo_owner[cob]
        view = views[node]
        assert view is not None
        for layout in _tpdos(view):
            pdo_owner[layout.cob_id] = node

    for node in node_ids:
        refresh(node)
    with Recording(path) as recording:
        for msg in recording:
            facts.frames = recording.frames
            if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
                continue
            cob = msg.arbitration_id
            if cob == SYNC_COB_ID:
                facts.sync_times.append(msg.timestamp)
                facts.sync_counters += len(msg.data) >= 1
                continue
            owner = pdo_owner.get(cob)
            if owner is not None:
                _pdo(patches[owner], views[owner], recording.frames, msg)
                continue
            function, node_id = cob & 0x780, cob & 0x7F
            if node_id not in patches:
                continue
            if function == HEARTBEAT and len(msg.data) == 1 and msg.data[0] != 0:
                patches[node_id].heartbeat_times.append(msg.timestamp)
            elif function in (SDO_TX, SDO_RX):
                _, observed = sdo.decode(node_id, function == SDO_RX, bytes(msg.data),
                                         views[node_id])
                if observed is not None:
                    index, subindex, raw = observed
                    _observe(patches[node_id], index, subindex, raw)
                    dictionary.observe(node_id, index, subindex, raw)
                    views[node_id] = dictionary.view(node_id)
                    if index in PDO_PARAMETERS:
                        refresh(node_id)
    return facts


def _pdo(patch: PatchFacts, view: NodeView | None, frame: int, msg: can.Message) -> None:
    assert view is not None
    patch.pdo_frames += 1
    patch.fd_frames += msg.is_fd
    entry = view.pdos.get(msg.arbitration_id)
    if entry is not None:  # a CAN FD frame is padded up to the next FD length
        size, length = entry.layout.size, len(msg.data)
        patch.wrong_length_frames += length < size or (not msg.is_fd and length != size)
    layouts = _tpdos(view)
    if patch.first_pdo_frame is None:
        patch.first_pdo_frame, patch.layouts = frame, layouts
    elif layouts != patch.layouts and patch.remapped_frame is None:
        patch.remapped_frame = frame


def _observe(patch: PatchFacts, index: int, subindex: int, raw: bytes) -> None:
    if index in PDO_PARAMETERS and patch.first_pdo_frame is None:
        patch.mapping_from_sdo = True
    elif index == HEARTBEAT_TIME and subindex == 0 and len(raw) >= 2:
        patch.heartbeat_ms_written = int.from_bytes(raw[:2], "little")
    elif index == LSB and subindex == 0 and len(raw) >= 4:
        patch.lsb_ohm = decode_si(index, subindex, raw)
    elif index == NOMINAL and 1 <= subindex <= 27 and len(raw) >= 4:
        ohm = decode_si(index, subindex, raw)
        if ohm is not None:
            patch.r0_ohm[subindex] = ohm
