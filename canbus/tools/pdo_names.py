"""What a node's PDOs carry, as named values in units, from its EDS and what the bus said.

A :class:`NodeView` starts from the EDS defaults (``canbus.pdo_codec.read_defaults``) and
follows the SDO values it is shown (:meth:`NodeView.observe`): PDO communication and
mapping parameters, the heartbeat time, the resistance LSB. So a mapping a master reads
or writes by SDO is the mapping the view decodes with.

Units: an EDS ``Factor``/``Unit`` (canopen reads both) applies to any node. The shipped
products add theirs: a patch's resistance codes (0x2000) are ohms by its LSB (0x2001)
with the reserved codes named (short, saturated, open); a force node's forces (0x2000,
INTEGER16 mN) are newtons with 0x8000 as "no value"; taxel status bytes and the valid
taxel mask (0x2005) are spelled out; its contact summary (0x2008) is in N, N·m and mm with
the state bits named, and the PDO that carries only it is labelled ``contact``.

:class:`~canbus.tools.pdo_dictionary.Dictionary` chooses the EDS per node-ID: 1..64 the
patch, 65..127 the force node (the host's default is patch node-ID + 64), unless told
otherwise; an identity read by SDO (0x1018:02 product code) switches a node to the shipped
EDS of that product.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import canopen
import numpy as np

from canbus import contact_record
from canbus.identity import FORCE_PRODUCT, PATCH_PRODUCT
from canbus.mappings import force_fd_entries, patch_fd_entries
from canbus.patch_constants import LSB_SCALE, scale_of
from canbus.pdo_codec import (
    COB_ID_INVALID,
    PdoCodec,
    Reader,
    TpdoLayout,
    read_defaults,
    read_layouts,
)
from canbus.tools.pdo_values import (
    CIA301_UNITS,
    UNSIGNED32,
    NamedValue,
    contact_value,
    counted_value,
    force_value,
    reason_value,
    resistance_value,
    scaled_value,
    status_value,
    valid_taxels_value,
    var_size,
)
from skin.errors import ConfigError

SHIPPED_BY_PRODUCT = {PATCH_PRODUCT: "skin-patch", FORCE_PRODUCT: "skin-forces"}
RPDO_COMM, RPDO_MAP, TPDO_COMM, TPDO_MAP = 0x1400, 0x1600, 0x1800, 0x1A00
_PDO_LAST = 0x1BFF  # RPDO/TPDO communication and mapping parameters: 0x1400..0x1BFF
_PILLARS, _AXES = "zxy", "xyz"
EdsChoice = str | os.PathLike[str]


@dataclass(frozen=True, slots=True)
class PdoEntry:
    """A PDO the node sends (``TPDO``) or receives (``RPDO``), with its own codec."""

    kind: str
    layout: TpdoLayout
    codec: PdoCodec

    @property
    def label(self) -> str:
        label = f"{self.kind}{self.layout.number}"
        contact = contact_record.CONTACT
        if self.layout.entries and all(e.index == contact for e in self.layout.entries):
            return f"{label} contact"
        return label


def shipped_default(node_id: int) -> str:
    """The shipped EDS a node-ID gets unless told otherwise."""
    return "skin-patch" if node_id <= 64 else "skin-forces"


class NodeView:
    """One node's object dictionary plus the values seen on the bus.

    ``od`` may have been loaded for another node-ID, ``od_node_id``, of the same EDS (it is
    only read): defaults the EDS gives relative to ``$NODEID`` are moved to this node.
    """

    def __init__(self, node_id: int, od: canopen.ObjectDictionary,
                 od_node_id: int | None = None) -> None:
        self.node_id = node_id
        self.od = od
        self._shift = node_id - (node_id if od_node_id is None else od_node_id)
        info = od.device_information
        self.product = int(info.product_number or 0)
        self.name = {PATCH_PRODUCT: "patch", FORCE_PRODUCT: "forces"}.get(self.product, "node")
        self.seen: dict[tuple[int, int], int] = {}
        self.heartbeat_ms: int | None = self._default(0x1017, 0)
        lsb = self._variable(0x2001, 0)
        self.lsb_ohm = LSB_SCALE.to_si(int(lsb.default)) if self.product == PATCH_PRODUCT \
            and lsb is not None and lsb.default is not None else 0.05
        self.pdos: dict[int, PdoEntry] = {}
        self._tpdos: tuple[TpdoLayout, ...] = ()
        self._namers: dict[tuple[int, int], Callable[[float], NamedValue]] = {}
        self._rebuild()

    @property
    def label(self) -> str:
        return f"{self.name} {self.node_id}"

    def observe(self, index: int, subindex: int, raw: bytes) -> bool:
        """A value of ``index:subindex`` seen in an SDO transfer; True if the PDO table changed
        (or a PDO's COB-ID is now known from the bus)."""
        var = self._variable(index, subindex)
        if var is None:
            return False
        try:
            value = var.decode_raw(raw[: var_size(var) or len(raw)])
        except (ValueError, TypeError, IndexError, UnicodeDecodeError):
            return False
        if index == 0x1017 and subindex == 0 and isinstance(value, int):
            self.heartbeat_ms = value
        if index == 0x2001 and self.product == PATCH_PRODUCT and isinstance(value, int) \
                and value > 0:
            self.lsb_ohm = LSB_SCALE.to_si(value)
            self._namers.clear()
        if not RPDO_COMM <= index <= _PDO_LAST or not isinstance(value, int):
            return False
        told = subindex == 1 and (index, subindex) not in self.seen and \
            (RPDO_COMM <= index < RPDO_MAP or TPDO_COMM <= index < TPDO_MAP)
        self.seen[(index, subindex)] = value
        return self._rebuild() or told  # a COB-ID now known from the bus, not the EDS

    def tpdo_layouts(self) -> list[TpdoLayout]:
        """The node's valid TPDOs, from the EDS defaults and the SDO values seen, of any
        length (a CAN FD PDO too); a TPDO whose mapping is half-way through a rewrite
        (an entry the dictionary does not have), or was only partly seen being rewritten
        (:meth:`mapping_known`), is left out, the others kept."""
        return list(self._tpdos)

    def mapping_known(self, mapping: int) -> bool:
        """Whether the mapping at ``mapping`` (0x1A00.., 0x1600..) is known: the EDS default
        while no SDO transfer touched it, else its count and every entry up to the count
        seen (a whole rewrite, or a whole read-back). A recording that begins in the middle
        of a master's rewrite shows some entries and not others: such a mapping is not
        guessed from the EDS."""
        touched = [sub for index, sub in self.seen if index == mapping]
        if not touched:
            return True
        count = self.seen.get((mapping, 0))
        return count is not None and all((mapping, sub) in self.seen
                                         for sub in range(1, count + 1))

    def _layouts(self, comm: int, mapping: int) -> list[TpdoLayout]:
        read, layouts = self._reader(), []
        number = 0
        while comm + number in self.od and mapping + number in self.od:
            if self.mapping_known(mapping + number):
                try:
                    found = read_layouts(read, 1, comm=comm + number,
                                         mapping=mapping + number)
                except (ConfigError, KeyError):
                    found = []
                layouts += [dataclasses.replace(layout, number=number + 1) for layout in found]
            number += 1
        return layouts

    def adopt_fd(self, mode: str = "xyz") -> bool:
        """Take canskin's CAN FD mapping (``canbus.mappings``): the node's whole answer or
        sample in TPDO 1, every other TPDO invalid, as if a master's SDO writes had been seen.
        False (nothing changed) for a node that is not a canskin patch or force node."""
        if self.product == FORCE_PRODUCT:
            entries = force_fd_entries()
        elif self.product == PATCH_PRODUCT:
            entries = patch_fd_entries(mode)
        else:
            return False
        read, n = self._reader(), 1
        while TPDO_COMM + n in self.od:
            self.seen[(TPDO_COMM + n, 1)] = read(TPDO_COMM + n, 1) | COB_ID_INVALID
            n += 1
        self.seen[(TPDO_MAP, 0)] = len(entries)
        for sub, entry in enumerate(entries, start=1):
            self.seen[(TPDO_MAP, sub)] = entry.to_raw()
        return self._rebuild()

    def pin(self, *, layouts: Sequence[TpdoLayout] | None = None,
            cob_ids: Sequence[int] | None = None) -> bool:
        """What a user's configuration says of the node, as if a master's SDO writes had
        been seen: its whole TPDO mapping (``layouts``; every other TPDO invalid), or only
        its TPDO COB-IDs (TPDO 1, 2, ... in order). True if the PDO table changed."""
        read = self._reader()
        if layouts is not None:
            by_number = {layout.number: layout for layout in layouts}
            number = 0
            while TPDO_COMM + number in self.od and TPDO_MAP + number in self.od:
                layout = by_number.get(number + 1)
                if layout is None:
                    self.seen[(TPDO_COMM + number, 1)] = read(TPDO_COMM + number, 1) \
                        | COB_ID_INVALID
                else:
                    self.seen[(TPDO_COMM + number, 1)] = layout.cob_id
                    self.seen[(TPDO_MAP + number, 0)] = len(layout.entries)
                    for sub, entry in enumerate(layout.entries, start=1):
                        self.seen[(TPDO_MAP + number, sub)] = entry.to_raw()
                number += 1
        for number, cob_id in enumerate(cob_ids or ()):
            self.seen[(TPDO_COMM + number, 1)] = int(cob_id)
        return self._rebuild()

    def forget_pdo_parameters(self) -> bool:
        """Drop every PDO parameter seen (the node booted: it starts again from its stored,
        usually default, parameters). True if the PDO table changed."""
        for key in [k for k in self.seen if RPDO_COMM <= k[0] <= _PDO_LAST]:
            del self.seen[key]
        return self._rebuild()

    def told(self, entry: PdoEntry) -> bool:
        """The PDO's COB-ID was seen (an SDO value, or pinned), not taken from the EDS."""
        comm = TPDO_COMM if entry.kind == "TPDO" else RPDO_COMM
        return (comm + entry.layout.number - 1, 1) in self.seen

    def fd_frame(self, cob_id: int, length: int) -> bool:
        """A CAN FD frame of ``length`` bytes came on ``cob_id``: if it is the node's TPDO 1
        and longer than its mapping, the node was mapped for CAN FD in place (a host's own
        force node): adopt that mapping. True if the PDO table changed."""
        entry = self.pdos.get(cob_id)
        if entry is None or length <= max(entry.layout.size, 8) or entry.layout.number != 1:
            return False
        return self.adopt_fd("xyz" if length > 20 else "z")

    def decode_pdo(self, cob_id: int, data: bytes) -> list[NamedValue] | None:
        """The named values of PDO ``cob_id``; None if the node has no such PDO or it is short."""
        return self.decode_pdos(cob_id, [data])[0]

    def decode_pdos(self, cob_id: int, payloads: Sequence[bytes]
                    ) -> list[list[NamedValue] | None]:
        """Many frames of one PDO at once (one numpy unpack); None for a frame too short."""
        out: list[list[NamedValue] | None] = [None] * len(payloads)
        entry = self.pdos.get(cob_id)
        if entry is None:
            return out
        whole = [k for k, p in enumerate(payloads) if len(p) >= entry.layout.size]
        if not whole:
            return out
        width = entry.codec.width  # 8, or a CAN FD PDO's length
        joined = b"".join(bytes(payloads[k][:width]).ljust(width, b"\0") for k in whole)
        values = entry.codec.unpack(np.frombuffer(joined, dtype=np.uint8).reshape(-1, 1, width))
        namers = [self.namer(index, subindex) for index, subindex in entry.codec.variables]
        for k, row in zip(whole, values.tolist(), strict=True):
            out[k] = [name(value) for name, value in zip(namers, row, strict=True)]
        return out

    def named(self, index: int, subindex: int, value: float) -> NamedValue:
        """``value`` (as the object holds it) of ``index:subindex`` in its unit."""
        return self.namer(index, subindex)(value)

    def namer(self, index: int, subindex: int) -> Callable[[float], NamedValue]:
        """The function that names and scales values of ``index:subindex`` (cached)."""
        key = (index, subindex)
        if key not in self._namers:
            self._namers[key] = self._make_namer(index, subindex)
        return self._namers[key]

    def _make_namer(self, index: int, subindex: int) -> Callable[[float], NamedValue]:
        product = self.product
        if product == PATCH_PRODUCT and index == 0x2000 and subindex:
            taxel, pillar = divmod(subindex - 1, 3)
            name, lsb = f"R{taxel}{_PILLARS[pillar]}", self.lsb_ohm
            return lambda value: resistance_value(name, int(value), lsb)
        if product == FORCE_PRODUCT and index == 0x2000 and subindex:
            taxel, axis = divmod(subindex - 1, 3)
            return functools.partial(force_value, f"F{taxel}{_AXES[axis]}")
        if product == PATCH_PRODUCT and index == 0x2004 and subindex:
            return lambda value: status_value(f"S{subindex - 1}", int(value))
        if product == FORCE_PRODUCT and index == 0x2004 and subindex:
            return lambda value: reason_value(f"S{subindex - 1}", int(value))
        if product == FORCE_PRODUCT and index == 0x2005:
            return valid_taxels_value
        if product == FORCE_PRODUCT and index == contact_record.CONTACT and \
                1 <= subindex <= contact_record.SUBS:
            return functools.partial(contact_value, subindex)
        if index == 0x1001:
            return lambda value: NamedValue("ER", value, "", f"ER=0x{int(value):02X}")
        var = self._variable(index, subindex)
        name = var.name if var is not None else f"0x{index:04X}:{subindex:02X}"
        factor = var.factor if var is not None else 1.0
        unit = (var.unit if var is not None else "") or CIA301_UNITS.get(index, "")
        scale = scale_of(index, subindex) if product == PATCH_PRODUCT else None
        if scale is not None:  # a physical constant as a count of a small unit: in SI
            digits = max(0, round(-math.log10(scale.si_per_count)))
            return functools.partial(counted_value, name, scale.si_per_count, digits,
                                     scale.si_unit)
        return functools.partial(scaled_value, name, factor, unit)

    def object_name(self, index: int, subindex: int) -> str:
        """``0x1018:01 Identity object.Vendor-ID`` (the name if the EDS has the object)."""
        var = self._variable(index, subindex)
        where = f"0x{index:04X}:{subindex:02X}"
        return f"{where} {var.qualname}" if var is not None else where

    def format_raw(self, index: int, subindex: int, raw: bytes) -> str:
        """An SDO value as the object's type says, in its unit where one is known."""
        var = self._variable(index, subindex)
        if var is None:
            return raw.hex(" ")
        try:
            value = var.decode_raw(raw[: var_size(var) or len(raw)])
        except (ValueError, TypeError, IndexError, UnicodeDecodeError):
            return raw.hex(" ")
        if isinstance(value, str):
            return repr(value)
        if isinstance(value, bytes | bytearray):
            return bytes(value).hex(" ")
        if var.data_type == UNSIGNED32 and index < 0x2000:
            return f"0x{int(value):08X}"
        return self.named(index, subindex, float(value)).text.split("=", 1)[1]

    def _variable(self, index: int, subindex: int) -> canopen.objectdictionary.ODVariable | None:
        try:
            obj = self.od[index]
        except KeyError:
            return None
        if isinstance(obj, canopen.objectdictionary.ODVariable):
            return obj if subindex == 0 else None
        if isinstance(obj, canopen.objectdictionary.ODArray) and subindex > 0:
            count = obj[0].default  # canopen invents any sub-index of an ARRAY; we do not
            if subindex not in obj.subindices and (count is None or subindex > int(count)):
                return None  # (0x1003's entries are in the EDS, its count starts at 0)
        try:
            return obj[subindex]
        except KeyError:
            return None

    def _default(self, index: int, subindex: int) -> int | None:
        var = self._variable(index, subindex)
        return None if var is None or var.default is None else int(var.default)

    def _reader(self) -> Reader:
        defaults, shift = read_defaults(self.od), self._shift

        def read(index: int, subindex: int) -> int:
            key = (index, subindex)
            if key in self.seen:
                return self.seen[key]
            var = self._variable(index, subindex)
            relative = var is not None and var.relative
            return defaults(index, subindex) + (shift if relative else 0)

        return read

    def _rebuild(self) -> bool:
        table = {}
        for kind, comm, mapping in (("TPDO", TPDO_COMM, TPDO_MAP), ("RPDO", RPDO_COMM, RPDO_MAP)):
            layouts = self._layouts(comm, mapping)
            if kind == "TPDO":
                self._tpdos = tuple(layouts)
            for layout in layouts:
                try:
                    table[layout.cob_id] = PdoEntry(kind, layout, PdoCodec([layout], self.od))
                except (ConfigError, KeyError, ValueError):
                    continue  # an entry the dictionary does not have: keep the rest
        changed = {c: e.layout for c, e in table.items()} != \
            {c: e.layout for c, e in self.pdos.items()}
        self.pdos = table
        return changed
