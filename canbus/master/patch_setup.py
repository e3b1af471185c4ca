"""Configuring one patch over SDO: read its constants, write its TPDO mapping and heartbeat.

The host reads 0x2001 (resistance LSB), 0x2002 (nominal resistances R0) and 0x2003
(sensor constants), writes the TPDO mapping of the decoder's mode with the CiA 301
sequence (invalidate, sub-index 0 = 0, entries, sub-index 0 = count, validate; unused
TPDOs invalid), synchronous transmission (type 1), and the producer heartbeat time
0x1017. The :class:`~canbus.pdo_codec.PdoCodec` is built from what was written, so the
data plane decodes exactly the layout the patch was told to send.

A listen-only host (another master configures the patches) builds the same
:class:`PatchSetup` without SDO: :func:`patch_info` is what :func:`read_patch_info` would
read from a patch with given constants (every value through the scaled UNSIGNED32 the
patch stores, ``canbus.patch_constants``), and :func:`plan_setup` is the mapping
:func:`setup_patch` writes for a mode.
"""

from __future__ import annotations

import logging
import struct
from dataclasses import dataclass

import canopen
import numpy as np
from canopen.sdo.client import SdoClient
from numpy.typing import ArrayLike, NDArray

from canbus.mappings import patch_fd_entries
from canbus.master.cobids import predefined_tpdo_cob_ids
from canbus.master.hostconfig import TPDO_COUNT, PatchConfig
from canbus.patch_constants import (
    CONSTANT_SCALES,
    LSB_SCALE,
    R0_SCALE,
    constant_counts,
    reported_constants,
    reported_refusal,
)
from canbus.pdo_codec import COB_ID_INVALID, TPDO_COMM, TPDO_MAP, MappedEntry, PdoCodec, TpdoLayout
from skin.constants import DEFAULT_CONSTANTS, TAXELS_PER_PATCH, SensorConstants
from skin.errors import SkinError

logger = logging.getLogger(__name__)

RESISTANCES, LSB, NOMINAL, CONSTANTS, ANSWERED = 0x2000, 0x2001, 0x2002, 0x2003, 0x2006
HEARTBEAT_TIME = 0x1017
SYNCHRONOUS = 1  # transmission type: every SYNC
ENTRIES_PER_TPDO = 4  # 4 x UNSIGNED16 = 8 bytes
_U8, _U16, _U32 = struct.Struct("<B"), struct.Struct("<H"), struct.Struct("<I")


class ReportedValueError(SkinError, ValueError):
    """A patch reports a value outside the range a real patch can have (an R0 of 0, a
    Young's modulus of 0xFFFFFFFF Pa ...): the host cannot decode with it."""


@dataclass(frozen=True)
class PatchInfo:
    """What a patch says about itself."""

    node_id: int
    lsb_ohm: float
    r0_ohm: NDArray[np.float64]  # (9, 3) pillars z, x, y
    constants: SensorConstants


@dataclass(frozen=True)
class PatchSetup:
    """A configured patch: its info, the mode the host mapped and the codec of that mapping."""

    info: PatchInfo
    mode: str
    layouts: tuple[TpdoLayout, ...]
    codec: PdoCodec

    @property
    def pillars(self) -> int:
        return 1 if self.mode == "z" else 3


def read_patch_info(sdo: SdoClient, node_id: int) -> PatchInfo:
    """Upload 0x2001, 0x2002 (27 values) and 0x2003 (E, rho, L, S, max strain, full-scale
    force, taxel pitch), each an UNSIGNED32 count of the unit its name gives
    (``canbus.patch_constants``)."""

    def count(index: int, subindex: int) -> int:
        return int(_U32.unpack(sdo.upload(index, subindex)[:4].ljust(4, b"\0"))[0])

    return _reported(node_id, count(LSB, 0), [count(NOMINAL, k) for k in range(1, 28)],
                     [count(CONSTANTS, s) for s in range(1, len(CONSTANT_SCALES) + 1)])


def patch_info(node_id: int, constants: SensorConstants = DEFAULT_CONSTANTS,
               r0_ohm: ArrayLike | None = None) -> PatchInfo:
    """What :func:`read_patch_info` reads from a patch holding ``constants`` and ``r0_ohm``
    (``(9, 3)`` or anything that broadcasts to it, pillars z, x, y; default the nominal
    R0 of ``constants``, as a patch reports at power-on), without asking it."""
    r0 = constants.nominal_resistance_ohm if r0_ohm is None else r0_ohm
    table = np.broadcast_to(np.asarray(r0, dtype=np.float64), (TAXELS_PER_PATCH, 3))
    return _reported(node_id, LSB_SCALE.to_count(constants.resistance_lsb_ohm),
                     [R0_SCALE.to_count(v) for v in table.reshape(-1).tolist()],
                     constant_counts(constants))


def _reported(node_id: int, lsb: int, r0: list[int], fields: list[int]) -> PatchInfo:
    """A patch's info from its counts (0x2001, 0x2002 sub 1..27, 0x2003 sub 1..7); a
    ReportedValueError names the first of 0x2001 and 0x2003 outside its range."""
    refusal = reported_refusal(lsb, fields)
    if refusal is not None:
        raise ReportedValueError(f"patch {node_id} reports {refusal}")
    table = np.array([R0_SCALE.to_si(v) for v in r0], dtype=np.float64)
    constants = reported_constants(lsb, fields)
    return PatchInfo(node_id, constants.resistance_lsb_ohm,
                     table.reshape(TAXELS_PER_PATCH, 3), constants)


def tpdo_layouts(node_id: int, mode: str, *, fd: bool = False) -> tuple[TpdoLayout, ...]:
    """The mapping for ``mode``: xyz = 27 codes, 4 per TPDO, in TPDO 1..7; z = pillar z of
    each taxel, one grid row (3 taxels) per TPDO, in TPDO 1..3. Predefined COB-IDs.

    ``fd`` (a CAN FD bus): the whole answer in TPDO 1, the codes (27 or 9) then 0x2006, the
    counter of the SYNC answered (55 or 19 bytes: one 64- or 20-byte CAN FD frame)."""
    if fd:
        return (TpdoLayout(1, predefined_tpdo_cob_ids(node_id)[0], patch_fd_entries(mode)),)
    if mode == "xyz":
        subs = list(range(1, 28))
        groups = [subs[k:k + ENTRIES_PER_TPDO] for k in range(0, 27, ENTRIES_PER_TPDO)]
    elif mode == "z":
        groups = [[3 * t + 1 for t in range(3 * row, 3 * row + 3)] for row in range(3)]
    else:
        raise ValueError(f"mode must be 'z' or 'xyz', got {mode!r}")
    cob_ids = predefined_tpdo_cob_ids(node_id)
    return tuple(TpdoLayout(n + 1, cob_ids[n], tuple(MappedEntry(RESISTANCES, s, 16)
                                                     for s in group))
                 for n, group in enumerate(groups))


def write_tpdo_mapping(sdo: SdoClient, node_id: int, layouts: tuple[TpdoLayout, ...]) -> None:
    """Write ``layouts`` with the CiA 301 sequence; every other TPDO is invalidated."""
    by_number = {layout.number: layout for layout in layouts}
    defaults = predefined_tpdo_cob_ids(node_id)
    for n in range(1, TPDO_COUNT + 1):
        comm, mapping = TPDO_COMM + n - 1, TPDO_MAP + n - 1
        layout = by_number.get(n)
        cob_id = layout.cob_id if layout is not None else defaults[n - 1]
        sdo.download(comm, 1, _U32.pack(cob_id | COB_ID_INVALID))
        if layout is None:
            continue
        sdo.download(comm, 2, _U8.pack(SYNCHRONOUS))
        sdo.download(mapping, 0, _U8.pack(0))
        for s, entry in enumerate(layout.entries, start=1):
            sdo.download(mapping, s, _U32.pack(entry.to_raw()))
        sdo.download(mapping, 0, _U8.pack(len(layout.entries)))
        sdo.download(comm, 1, _U32.pack(cob_id))


def plan_setup(node_id: int, od: canopen.ObjectDictionary, mode: str,
               info: PatchInfo, *, fd: bool = False) -> PatchSetup:
    """The set-up :func:`setup_patch` makes for ``mode`` (on a CAN FD bus: ``fd``): the TPDO
    layouts it writes and their codec, for a patch that reports ``info``. Nothing is sent."""
    layouts = tpdo_layouts(node_id, mode, fd=fd)
    return PatchSetup(info, mode, layouts, PdoCodec(layouts, od))


def setup_patch(node: canopen.RemoteNode, mode: str, *, heartbeat_ms: int,
                fd: bool = False) -> PatchSetup:
    """Read the patch's info, map its TPDOs for ``mode`` and set its heartbeat.

    The node should be PRE-OPERATIONAL (the caller sends the NMT command); SDO errors
    (``canopen.SdoError``) propagate.
    """
    node_id = int(node.id or 0)
    info = read_patch_info(node.sdo, node_id)
    setup = plan_setup(node_id, node.object_dictionary, mode, info, fd=fd)
    write_tpdo_mapping(node.sdo, node_id, setup.layouts)
    node.sdo.download(HEARTBEAT_TIME, 0, _U16.pack(heartbeat_ms))
    return setup


def check_reported(info: PatchInfo, pillars: int = 3) -> None:
    """Refuse an R0 (of the pillars decoded) outside the range a real patch can have,
    naming the object, sub-index, taxel, pillar, value and range (ReportedValueError).
    (0x2001 and 0x2003 are checked as they are read: :func:`read_patch_info`.)"""
    r0 = info.r0_ohm[:, :pillars]
    bad = np.argwhere(~((r0 >= R0_SCALE.low) & (r0 <= R0_SCALE.high)))
    if not len(bad):
        return
    taxel, pillar = (int(v) for v in bad[0])
    value = float(r0[taxel, pillar])
    where = f"0x{NOMINAL:04X} sub {3 * taxel + pillar + 1}"
    name = f"R0 of taxel {taxel}, pillar {'zxy'[pillar]}"
    refusal = R0_SCALE.refusal(where, R0_SCALE.count_of(value), name) \
        if np.isfinite(value) else f"{where} ({name}) = {value!r} Ω: outside the range"
    more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
    raise ReportedValueError(f"patch {info.node_id} reports {refusal}{more}")


def configured_info(patch: PatchConfig) -> PatchInfo:
    """What a patch holding the configured constants and R0 (default: ``DEFAULT_CONSTANTS``
    and its nominal R0) reports over SDO."""
    r0 = None if patch.r0_ohm is None else np.reshape(patch.r0_ohm, (-1, 3))
    return patch_info(patch.node_id, patch.constants or DEFAULT_CONSTANTS, r0)


def warn_if_unlike_config(patch: PatchConfig, info: PatchInfo) -> None:
    """The config's constants and R0 (for listen-only use) against what the patch reports."""
    expected = configured_info(patch)
    if patch.constants is not None and expected.constants != info.constants:
        logger.warning("patch %d reports constants %s, the config says %s: decoding with the "
                       "patch's", patch.node_id, info.constants, expected.constants)
    if patch.r0_ohm is not None and not np.array_equal(expected.r0_ohm, info.r0_ohm):
        logger.warning("patch %d reports another R0 than the config's r0_ohm: decoding with "
                       "the patch's", patch.node_id)
