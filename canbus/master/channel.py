"""What the data plane knows of each patch: its channel (PDO mapping, decoder, force
node), its answer slot (the precomputed layout of one answer and what arrived of it in the
open cycle), the samples it queues, the force frames it publishes and its counters."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from canbus.answers import PatchAnswer
from canbus.master.baseline import Baseline
from canbus.master.forcenode import ForceNode
from canbus.pdo_codec import PdoCodec
from decoder.protocol import Decoder
from skin.constants import DEFAULT_CONSTANTS, TAXELS_PER_PATCH
from skin.contact_state import ContactSummary
from skin.errors import ConfigError
from skin.placement import PatchOnLink, PatchPlacement, on_link

RESISTANCES = 0x2000


@dataclass(frozen=True)
class ForceFrame:
    """One patch's forces for one SYNC cycle."""

    patch: int  # patch node-ID
    force_node: int  # force node-ID it was published as
    cycle: int  # host's SYNC cycle number (1, 2, ...), monotonic
    sync_counter: int  # the SYNC counter byte sent (0 without a counter)
    timestamp: float  # time.time() when the host sent that SYNC
    force_N: NDArray[np.float64]  # (9, 3) Fx, Fy, Fz; 0 N where not valid
    valid: NDArray[np.bool_]  # (9,)
    reason: NDArray[np.uint8]  # (9,) decoder.reasons codes; MISSING, FAULTY from the data plane
    complete: bool  # every TPDO of one answer of the patch arrived, in order, in the window
    published: bool  # the force TPDOs went onto the bus
    contact: ContactSummary | None = None  # net force, CoP, contact, slip (docs/contact.md)
    placement: PatchPlacement | None = field(default=None, repr=False)  # its link and pose
    pitch_m: float = field(default=DEFAULT_CONSTANTS.taxel_pitch_m, repr=False)

    @property
    def on_link(self) -> PatchOnLink | None:
        """The contact summary in the frame of the link the config places the patch on
        (docs/robot.md); None without a placement or a summary."""
        c = self.contact
        if self.placement is None or c is None:
            return None
        return on_link(self.patch, self.placement, self.pitch_m, self.force_N,
                       c.contact_taxels, c.cop_m, c.in_contact)


@dataclass
class PatchChannel:
    """Everything the data plane needs to turn one patch's PDOs into forces."""

    node_id: int
    codec: PdoCodec  # the patch's TPDOs as configured (maps 0x2000 codes; may map more)
    pillars: int  # 1 (z-only) or 3
    lsb_ohm: float  # the patch's 0x2001
    decoder: Decoder  # any registered decoder; r0 baked in by the host
    force_node: ForceNode
    scale: NDArray[np.float64] = field(default_factory=lambda: np.ones((TAXELS_PER_PATCH, 1)))
    """(9, P), or anything that broadcasts to it: multiplied onto resistances before decode
    (with a ``baseline``, its scale is used instead)."""
    masked: NDArray[np.bool_] = field(
        default_factory=lambda: np.zeros(TAXELS_PER_PATCH, dtype=bool))
    """(9,) taxels the host knows are faulty: invalid with ``Reason.FAULTY``."""
    baseline: Baseline | None = None
    """Tare and drift tracking: the data plane decodes with its scale, tracks drift on every
    complete sample and tares it (:meth:`DataPlane.tare`)."""
    answer_order: str = "cob-id"
    """The order in which the patch sends the TPDOs of one answer: ``"cob-id"`` (ascending
    identifier, as a node's queued frames leave on a CAN bus) or ``"tpdo"`` (TPDO number
    order, a device with a single FIFO transmit buffer)."""


@dataclass
class DataPlaneStats:
    """Counters since the data plane was built."""

    frames_in: int = 0  # PDO frames of known channels
    frames_out: int = 0  # force TPDOs sent
    unknown_frames: int = 0  # no node's traffic here: a PDO of no channel (a lost or removed
    # patch's, a stranger's), 29-bit, remote, outside the predefined set (frame_kinds)
    bus_frames: int = 0  # the bus's own traffic beside patch PDOs: SYNC, NMT, heartbeats,
    # EMCY, SDO, LSS, TIME, the force nodes' and other_nodes' PDOs
    duplicate_frames: int = 0  # a PDO already seen in its cycle
    late_frames: int = 0  # before the window, after it, or the tail of an earlier answer
    out_of_order_frames: int = 0  # ahead of its place in the answer, or after the answer ended
    second_answers: int = 0  # an answer began after a complete one in one window: the one
    # published was then most likely the previous SYNC's, whole (docs/host.md)
    stale_answers: int = 0  # an answer that names (0x2006) an earlier SYNC than its cycle's
    malformed_frames: int = 0  # shorter than the PDO's mapping
    samples: int = 0
    batches: int = 0  # publishing rounds: samples / batches is the mean decode batch
    complete_samples: int = 0
    incomplete_samples: int = 0
    steady_samples: int = 0  # of cycles opened once every patch of the bus was operational
    steady_complete_samples: int = 0  # (DataPlane.steady_from_cycle): the steady state
    decode_errors: int = 0  # decoder raised: those samples are dropped (logged)
    send_errors: int = 0  # bus.send raised: that sample is not published (logged)
    callback_errors: int = 0  # a subscriber raised (logged)

    def snapshot(self) -> dict[str, int]:
        return dataclasses.asdict(self)


class AnswerSlot(PatchAnswer):
    """A channel's answer in the open cycle (:class:`~canbus.answers.PatchAnswer`) and what
    decoding it needs: where the codes are in ``raw``, which taxels each PDO carries."""

    def __init__(self, channel: PatchChannel, key: int) -> None:
        codec = channel.codec
        super().__init__(channel.node_id, codec.layouts, answer_order=channel.answer_order)
        pdos = len(codec.layouts)
        self.channel = channel
        self.online = True
        self.key = key  # channels with equal keys are unpacked together
        p = channel.pillars
        try:
            self.columns = np.array([[codec.column(RESISTANCES, 3 * t + k + 1) for k in range(p)]
                                     for t in range(TAXELS_PER_PATCH)], dtype=np.intp)
        except ValueError as err:
            raise ConfigError("channel.codec", f"patch {channel.node_id}'s PDOs do not map "
                              f"every 0x2000 code of {p} pillar(s)") from err
        carried = np.zeros((pdos, TAXELS_PER_PATCH), dtype=bool)
        for n, layout in enumerate(codec.layouts):
            for entry in layout.entries:
                value = entry.subindex - 1
                if entry.index == RESISTANCES and value % 3 < p:
                    carried[n, value // 3] = True
        self.carried = carried  # (PDOs, 9): the taxels each PDO carries
        offsets = np.array([[self.offsets[(RESISTANCES, 3 * t + k + 1)] for k in range(p)]
                            for t in range(TAXELS_PER_PATCH)], dtype=np.intp)
        self.words: NDArray[np.intp] | None = None
        """(9, P) each code's place in ``raw`` read as little-endian UNSIGNED16 words, or
        None if a code starts at an odd byte (then ``codec.unpack`` reads them)."""
        u16 = all(codec.dtypes[c] == np.dtype("<u2") for c in self.columns.ravel().tolist())
        if u16 and not np.any(offsets % 2):
            self.words = offsets // 2

    def taxels_of(self, pdo_bits: int) -> NDArray[np.bool_]:
        """(9,) the taxels carried by the PDOs whose bits are set."""
        which = np.array([pdo_bits >> p & 1 for p in range(len(self.carried))], dtype=bool)
        taxels: NDArray[np.bool_] = self.carried[which].any(axis=0)
        return taxels


@dataclass(frozen=True)
class SampleJob:
    slot: AnswerSlot
    cycle: tuple[int, int, float]
    payload: bytes
    missing: int  # PDO bits absent or not trusted
    complete: bool


Subscriber = Callable[[list[ForceFrame]], None]


def rest_payload(slot: AnswerSlot) -> bytes:
    """The slot's raw bytes with every code at the decoder's zero-force resistance."""
    channel = slot.channel
    codec = channel.codec
    values = np.zeros((1, len(codec.variables)))
    rest = (channel.baseline.r0_ref if channel.baseline is not None else
            np.broadcast_to(DEFAULT_CONSTANTS.nominal_resistance_ohm[:channel.pillars],
                            (TAXELS_PER_PATCH, channel.pillars)))
    codes = np.clip(np.rint(rest / channel.lsb_ohm), 1, 0xFFFD)
    values[0, slot.columns.ravel()] = codes.ravel()
    packed = codec.pack(values)[0]  # (PDOs, width)
    raw = bytearray(slot.stride * len(codec.layouts))
    for p in range(len(codec.layouts)):
        raw[slot.stride * p:slot.stride * p + codec.width] = packed[p].tobytes()
    return bytes(raw)
