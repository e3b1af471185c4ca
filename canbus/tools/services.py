"""Which CANopen service a frame belongs to, and what it says, by the predefined connection set.

:func:`route` maps an 11-bit COB-ID to its service and node (CiA 301 predefined
connection set: NMT 0x000, SYNC 0x080, EMCY 0x080 + node, TIME 0x100, PDOs 0x180..0x57F,
SDO 0x580/0x600 + node, NMT error control 0x700 + node, LSS 0x7E4/0x7E5); a table
lookup, cheap enough for every received frame. :class:`ServiceDecoder` turns a frame
into one line of text: NMT commands and states, the SYNC counter, EMCY codes (canopen's
descriptions), SDO transfers by object name (it follows each node's transfer so a
segment knows its object) and PDOs as named values in units (``canbus.tools.pdo_names``).
"""

from __future__ import annotations

import datetime as dt
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

import can
from canopen.emcy import EmcyError
from canopen.sdo.exceptions import SdoAbortedError

from canbus.identity import PATCH_PRODUCT
from canbus.tools.attribution import Attribution
from canbus.tools.lss_names import describe_lss
from canbus.tools.pdo_dictionary import Dictionary
from canbus.tools.pdo_names import NodeView
from canbus.tools.pdo_values import describe_taxel_fault


class Service(StrEnum):
    NMT = "nmt"
    SYNC = "sync"
    EMCY = "emcy"
    TIME = "time"
    PDO = "pdo"
    SDO = "sdo"
    HEARTBEAT = "heartbeat"
    LSS = "lss"
    ERROR = "error"
    UNKNOWN = "unknown"


@dataclass(frozen=True, slots=True)
class Route:
    """What a COB-ID is in the predefined connection set."""

    service: Service
    node: int | None
    label: str


@dataclass(frozen=True, slots=True)
class Decoded:
    """One frame in words."""

    timestamp: float
    cob_id: int
    service: Service
    node: int | None
    label: str
    text: str

    @property
    def route(self) -> Route:
        return Route(self.service, self.node, self.label)


NMT_COMMANDS = {0x01: "start", 0x02: "stop", 0x80: "enter pre-operational",
                0x81: "reset node", 0x82: "reset communication"}
NMT_STATES = {0x00: "boot-up", 0x04: "stopped", 0x05: "operational", 0x7F: "pre-operational"}
PREDEFINED_PDOS = {0x180: "TPDO1", 0x200: "RPDO1", 0x280: "TPDO2", 0x300: "RPDO2",
                   0x380: "TPDO3", 0x400: "RPDO3", 0x480: "TPDO4", 0x500: "RPDO4"}
_ERROR_ROUTE = Route(Service.ERROR, None, "error frame")
_EXTENDED_ROUTE = Route(Service.UNKNOWN, None, "29-bit id")
_TIME_EPOCH = dt.datetime(1984, 1, 1, tzinfo=dt.UTC)


def _route_11bit(cob_id: int) -> Route:
    function, node = cob_id & 0x780, cob_id & 0x7F
    if cob_id == 0x000:
        return Route(Service.NMT, None, "NMT")
    if cob_id == 0x080:
        return Route(Service.SYNC, None, "SYNC")
    if cob_id == 0x100:
        return Route(Service.TIME, None, "TIME")
    if cob_id in (0x7E4, 0x7E5):
        return Route(Service.LSS, None, "LSS " + ("slave" if cob_id == 0x7E4 else "master"))
    if node == 0:
        return Route(Service.UNKNOWN, None, f"0x{cob_id:03X}")
    if function == 0x080:
        return Route(Service.EMCY, node, "EMCY")
    if function in PREDEFINED_PDOS:
        return Route(Service.PDO, node, PREDEFINED_PDOS[function])
    if function == 0x580:
        return Route(Service.SDO, node, "SDO tx")
    if function == 0x600:
        return Route(Service.SDO, node, "SDO rx")
    if function == 0x700:
        return Route(Service.HEARTBEAT, node, "heartbeat")
    return Route(Service.UNKNOWN, None, f"0x{cob_id:03X}")


_ROUTES = tuple(_route_11bit(c) for c in range(0x800))


def route(msg: can.Message) -> Route:
    """The service and node of a frame (error frames and 29-bit ids are not CANopen's)."""
    if msg.is_error_frame:
        return _ERROR_ROUTE
    if msg.is_extended_id or msg.arbitration_id > 0x7FF:
        return _EXTENDED_ROUTE
    return _ROUTES[msg.arbitration_id]


def describe_nmt(data: bytes) -> str:
    if len(data) != 2:
        return f"malformed NMT ({len(data)} bytes)"
    command = NMT_COMMANDS.get(data[0], f"command 0x{data[0]:02X}")
    return f"{command} {'all nodes' if data[1] == 0 else f'node {data[1]}'}"


def describe_sync(data: bytes) -> str:
    if len(data) == 0:
        return "SYNC"
    if len(data) == 1:
        return f"SYNC counter {data[0]}"
    return f"malformed SYNC ({len(data)} bytes)"


def describe_heartbeat(data: bytes) -> str:
    if len(data) != 1:
        return f"malformed heartbeat ({len(data)} bytes)"
    state = NMT_STATES.get(data[0] & 0x7F, f"state 0x{data[0] & 0x7F:02X}")
    return state if data[0] < 0x80 else f"{state} (toggle 1)"


def describe_time(data: bytes) -> str:
    if len(data) != 6:
        return f"malformed TIME ({len(data)} bytes)"
    millis, days = struct.unpack("<IH", data)
    when = _TIME_EPOCH + dt.timedelta(days=days, milliseconds=millis & 0x0FFF_FFFF)
    return f"TIME {when.isoformat(timespec='milliseconds')}"


def describe_emcy(data: bytes, view: NodeView | None) -> str:
    if len(data) != 8:
        return f"malformed EMCY ({len(data)} bytes)"
    code, register = struct.unpack_from("<HB", data)
    description = EmcyError(code, register, data[3:], 0.0).get_desc()
    text = f"0x{code:04X} {description}, ER 0x{register:02X}, data {data[3:].hex(' ')}"
    if view is not None and view.product == PATCH_PRODUCT and code in (0x0000, 0x5000):
        text += f" ({describe_taxel_fault(data[3], data[4])})"
    return text


@dataclass
class _Transfer:
    index: int
    subindex: int
    upload: bool
    buffer: bytearray
    complete: bool = False


Observed = tuple[int, int, bytes]
"""An object value an SDO transfer carried (index, subindex, raw little-endian bytes)."""


class SdoDecoder:
    """SDO frames of every node in words; remembers each node's transfer (one per server)."""

    def __init__(self) -> None:
        self._transfers: dict[int, _Transfer] = {}

    def decode(self, node: int, request: bool, data: bytes,
               view: NodeView | None) -> tuple[str, Observed | None]:
        if len(data) != 8:
            return f"malformed SDO ({len(data)} bytes)", None
        specifier = data[0] >> 5
        if specifier == 4:
            self._transfers.pop(node, None)
            index, subindex, code = struct.unpack_from("<HBI", data, 1)
            return f"abort {_name(view, index, subindex)}: {SdoAbortedError(code)}", None
        if request:
            return self._request(node, specifier, data, view)
        return self._response(node, specifier, data, view)

    def _request(self, node: int, ccs: int, data: bytes,
                 view: NodeView | None) -> tuple[str, Observed | None]:
        index, subindex = struct.unpack_from("<HB", data, 1)
        if ccs == 1:
            name = _name(view, index, subindex)
            if data[0] & 0x02:
                value = data[4:8 - ((data[0] >> 2) & 3 if data[0] & 0x01 else 0)]
                self._transfers[node] = _Transfer(index, subindex, False, bytearray(value), True)
                return f"write {name} = {_value(view, index, subindex, value)}", None
            self._transfers[node] = _Transfer(index, subindex, False, bytearray())
            size = f", {struct.unpack_from('<I', data, 4)[0]} bytes" if data[0] & 0x01 else ""
            return f"write {name} (segmented{size})", None
        if ccs == 2:
            self._transfers[node] = _Transfer(index, subindex, True, bytearray())
            return f"read {_name(view, index, subindex)}", None
        transfer = self._transfers.get(node)
        of = f" of {_name(view, transfer.index, transfer.subindex)}" if transfer else ""
        toggle = (data[0] >> 4) & 1
        if ccs == 0:
            segment = data[1:8 - ((data[0] >> 1) & 7)]
            last = data[0] & 0x01
            if transfer is not None and not transfer.upload:
                transfer.buffer += segment
                transfer.complete = bool(last)
            return (f"download segment{of}, toggle {toggle}, {len(segment)} bytes"
                    f"{', last' if last else ''}"), None
        if ccs == 3:
            return f"upload segment request{of}, toggle {toggle}", None
        return _block(ccs, data, view, request=True), None

    def _response(self, node: int, scs: int, data: bytes,
                  view: NodeView | None) -> tuple[str, Observed | None]:
        index, subindex = struct.unpack_from("<HB", data, 1)
        transfer = self._transfers.get(node)
        if scs == 2:
            name = _name(view, index, subindex)
            if data[0] & 0x02:
                self._transfers.pop(node, None)
                value = data[4:8 - ((data[0] >> 2) & 3 if data[0] & 0x01 else 0)]
                return f"{name} = {_value(view, index, subindex, value)}", \
                    (index, subindex, bytes(value))
            self._transfers[node] = _Transfer(index, subindex, True, bytearray())
            size = f"{struct.unpack_from('<I', data, 4)[0]} bytes" if data[0] & 0x01 else "size"
            return f"{name}: {size} follow in segments", None
        if scs == 3:
            name = _name(view, index, subindex)
            if transfer is not None and transfer.complete and \
                    (transfer.index, transfer.subindex) == (index, subindex):
                self._transfers.pop(node, None)
                return f"write {name} done", (index, subindex, bytes(transfer.buffer))
            return f"write {name} accepted", None
        toggle = (data[0] >> 4) & 1
        if scs == 0 and transfer is not None and transfer.upload:
            transfer.buffer += data[1:8 - ((data[0] >> 1) & 7)]
            if data[0] & 0x01:
                self._transfers.pop(node, None)
                raw = bytes(transfer.buffer)
                name = _name(view, transfer.index, transfer.subindex)
                return f"{name} = {_value(view, transfer.index, transfer.subindex, raw)}", \
                    (transfer.index, transfer.subindex, raw)
            return f"upload segment, toggle {toggle}, {len(transfer.buffer)} bytes so far", None
        if scs == 0:
            return f"upload segment, toggle {toggle}", None
        if scs == 1:
            if transfer is not None and transfer.complete:
                self._transfers.pop(node, None)
                name = _name(view, transfer.index, transfer.subindex)
                return f"write {name} done", (transfer.index, transfer.subindex,
                                              bytes(transfer.buffer))
            return f"download segment confirmed, toggle {toggle}", None
        return _block(scs, data, view, request=False), None


def _name(view: NodeView | None, index: int, subindex: int) -> str:
    return view.object_name(index, subindex) if view is not None else \
        f"0x{index:04X}:{subindex:02X}"


def _value(view: NodeView | None, index: int, subindex: int, raw: bytes) -> str:
    return view.format_raw(index, subindex, raw) if view is not None else raw.hex(" ")


def _block(specifier: int, data: bytes, view: NodeView | None, *, request: bool) -> str:
    """Block transfers: the initiation by object name; sub-block segments are not followed."""
    upload = (specifier == 5) == request  # ccs 5 / scs 6: upload; ccs 6 / scs 5: download
    if specifier not in (5, 6):
        return f"invalid SDO command 0x{data[0]:02X}"
    kind = "block upload" if upload else "block download"
    initiate_mask = 0x03 if specifier == 5 else 0x01
    if data[0] & initiate_mask == 0:
        index, subindex = struct.unpack_from("<HB", data, 1)
        return f"{kind} {_name(view, index, subindex)}"
    return f"{kind} ({data.hex(' ')})"


UNATTRIBUTED = "unattributed"
"""The label of a PDO-shaped frame no node is known to send (``canbus.tools.attribution``)."""
_PDO_SHAPED = frozenset((Service.PDO, Service.UNKNOWN))


class ServiceDecoder:
    """Frames in words, with the node's EDS; follows SDO transfers and NMT states.

    A PDO is put under the node that sends it by ``attribution``
    (:mod:`canbus.tools.attribution`), never by its COB-ID alone: a PDO no node is known to
    send is routed as ``Route(PDO, None, "unattributed")`` and shown as bytes.
    """

    def __init__(self, dictionary: Dictionary | None = None,
                 attribution: Attribution | None = None) -> None:
        self.dictionary = dictionary or (attribution.dictionary if attribution else Dictionary())
        self.attribution = attribution or Attribution(self.dictionary)
        self.sdo = SdoDecoder()
        self.states: dict[int, str] = {}
        self._routes: dict[int, Route] = {}
        self._routes_version = -1

    def route(self, msg: can.Message) -> Route:
        """:func:`route`, with a PDO-shaped frame put under the node that sends it."""
        where = route(msg)
        if where.service not in _PDO_SHAPED or msg.is_extended_id or msg.is_error_frame:
            return where
        if self._routes_version != self.dictionary.version:
            self._routes, self._routes_version = {}, self.dictionary.version
        cob = msg.arbitration_id
        found = self._routes.get(cob)
        if found is None:
            owner = self.attribution.owner(cob)
            found = Route(Service.PDO, owner.node, owner.label) if owner is not None else \
                Route(Service.PDO, None, UNATTRIBUTED) if where.service is Service.PDO \
                else where
            self._routes[cob] = found
        return found

    def node_label(self, node: int | None) -> str:
        if node is None:
            return ""
        view = self.dictionary.view(node)
        return view.label if view is not None else f"node {node}"

    def pdo_label(self, msg: can.Message, where: Route) -> str:
        view = self.dictionary.view(where.node) if where.node is not None else None
        entry = view.pdos.get(msg.arbitration_id) if view is not None else None
        return entry.label if entry is not None else where.label

    def decode(self, msg: can.Message, where: Route | None = None) -> Decoded:
        """One frame in words; feeds what SDO transfers reveal to the dictionary."""
        where = where or self.route(msg)
        data = bytes(msg.data)
        node, label = where.node, where.label
        view = self.dictionary.view(node) if node is not None else None
        service = where.service
        if service is Service.PDO and node is None:
            text = data.hex(" ") if not msg.is_remote_frame else f"remote request, DLC {msg.dlc}"
        elif service is Service.PDO:
            label = self.pdo_label(msg, where)
            text = self.describe_pdo(msg.arbitration_id, data, view)
        elif service is Service.SDO and node is not None:
            text, observed = self.sdo.decode(node, where.label == "SDO rx", data, view)
            if observed is not None:
                self.dictionary.observe(node, *observed)
        elif service is Service.HEARTBEAT and node is not None:
            text = describe_heartbeat(data)
            self.states[node] = text
        elif service is Service.NMT:
            text = describe_nmt(data)
        elif service is Service.SYNC:
            text = describe_sync(data)
        elif service is Service.EMCY:
            text = describe_emcy(data, view)
        elif service is Service.TIME:
            text = describe_time(data)
        elif service is Service.LSS:
            text = describe_lss(msg.arbitration_id, data)
        elif service is Service.ERROR:
            text = f"error frame class 0x{msg.arbitration_id:08X} {data.hex(' ')}".rstrip()
        else:
            text = data.hex(" ") if not msg.is_remote_frame else f"remote request, DLC {msg.dlc}"
        return Decoded(msg.timestamp, msg.arbitration_id, service, node, label, text)

    @staticmethod
    def describe_pdo(cob_id: int, data: bytes, view: NodeView | None) -> str:
        return ServiceDecoder.describe_pdos(cob_id, [data], view)[0]

    @staticmethod
    def describe_pdos(cob_id: int, payloads: Sequence[bytes], view: NodeView | None
                      ) -> list[str]:
        """Many frames of one PDO in words, decoded in one batch."""
        longest = max((len(p) for p in payloads), default=0)
        if view is not None and longest > 8:
            view.fd_frame(cob_id, longest)  # a force node mapped for CAN FD in place
        decoded = view.decode_pdos(cob_id, payloads) if view is not None else \
            [None] * len(payloads)
        entry = view.pdos.get(cob_id) if view is not None else None
        texts = []
        for values, data in zip(decoded, payloads, strict=True):
            if values is not None:
                texts.append(" ".join(v.text for v in values))
            elif entry is not None:
                texts.append(f"{bytes(data).hex(' ')} (length {len(data)}, mapping needs "
                             f"{entry.layout.size})")
            elif view is not None:
                texts.append(f"{bytes(data).hex(' ')} (not in the node's PDO mapping)")
            else:  # unattributed, or a node without an EDS here: its bytes only
                texts.append(bytes(data).hex(" "))
        return texts
