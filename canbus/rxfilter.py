"""What a bus hands this process: without the echoes of its own frames, and, where the
process owns the bus, only the frames it consumes, dropped at the cheapest point there is.

**Own frames.** python-can's ``udp_multicast`` loops every frame back to every socket of its
group on the machine, the sender's own included (IP multicast loopback, which the other
processes on the machine need; python-can refuses ``receive_own_messages=True`` and cannot
turn the echo off). So on that transport a process pays for each frame it sends twice: once
to send it, once to receive, unpack and dispatch its echo (about as much CPU again), and
counts it among what others sent. ``virtual``, ``timed`` and ``socketcan`` hand a bus its
own frames only when it asks (``receive_own_messages``), and then it wants them, so nothing
is dropped there. Each sender of a process claims the COB-IDs it alone sends
(:meth:`ReceiveFilter.claim`); a COB-ID has one transmitter in CiA 301, and NMT commands,
which any master may send, are never claimed.

**Consumed frames.** A device's CAN controller takes only the identifiers its acceptance
filter lets through; a process that owns a bus may do the same
(:meth:`ReceiveFilter.accept_only`: python-can's receive filters, which socketcan applies in
the kernel and the other interfaces in ``recv``).

**Where they are dropped.** ``udp_multicast`` on Linux: in the kernel, by a classic BPF
socket filter on the bus's socket that reads the COB-ID out of python-can's msgpack datagram
(no wake-up, no copy, no unpacking; :attr:`ReceiveFilter.in_kernel`). It passes what it
cannot read (another python-can's layout, a 29-bit id, a remote or error frame), so it never
drops a frame that is neither claimed nor outside an acceptance list. Anywhere else, and
behind the kernel filter as a second line: :meth:`ReceiveFilter.is_own` (one set lookup) in
front of a listener, e.g. :class:`OwnFrameGate` around canopen's, and python-can's filters.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import socket
import struct
import sys
import threading
import weakref
from collections.abc import Iterable

import can

from canbus.perbus import PerBus
from skin.inputs import fields

logger = logging.getLogger(__name__)

SO_ATTACH_FILTER, SO_DETACH_FILTER = 26, 27
BPF_MAXINSNS = 4096
_UDP_HEADER = 8  # a UDP socket's filter sees the datagram from its UDP header on


def echoes_own_frames(bus: can.BusABC) -> bool:
    """Whether ``bus`` hands its process its own frames back without being asked (a
    ``canbus.busio.ResilientBus``: whether the bus it wraps does)."""
    bus = getattr(bus, "wrapped", None) or bus
    try:
        from can.interfaces.udp_multicast import UdpMulticastBus
    except ImportError:  # pragma: no cover - msgpack missing: no udp_multicast either
        return False
    return isinstance(bus, UdpMulticastBus)


def _cob_ids(cob_ids: Iterable[int]) -> frozenset[int]:
    return frozenset(fields.cob_id(int(c), "COB-ID") for c in cob_ids)


class ReceiveFilter:
    """What one bus passes to this process: claims of own COB-IDs, an acceptance list."""

    def __init__(self, bus: can.BusABC) -> None:
        self._bus = weakref.ref(bus)
        self.echoes = echoes_own_frames(bus)
        self.in_kernel = False
        """The bus's socket drops the frames itself (udp_multicast on Linux)."""
        self._claims: dict[int, frozenset[int]] = {}
        self._owners: dict[int, weakref.ref[object] | None] = {}
        self._lock = threading.Lock()
        self.cob_ids: frozenset[int] = frozenset()
        """Every claimed COB-ID: 11-bit data frames this process alone sends."""
        self.accepted: frozenset[int] | None = None
        """The acceptance list (None: every frame)."""

    def claim(self, owner: object, cob_ids: Iterable[int]) -> None:
        """``owner`` sends ``cob_ids`` on this bus (replacing what it claimed before)."""
        ids = _cob_ids(cob_ids)
        if 0 in ids:
            raise ValueError("NMT's 0x000 is sent by any master: it cannot be claimed")
        with self._lock:
            self._claims[id(owner)] = ids
            self._owners[id(owner)] = _weak(owner)
            self._update()

    def release(self, owner: object) -> None:
        """``owner`` sends nothing more on this bus."""
        with self._lock:
            self._claims.pop(id(owner), None)
            self._owners.pop(id(owner), None)
            self._update()

    def accept_only(self, cob_ids: Iterable[int] | None) -> None:
        """Pass only these 11-bit data frames to the process (None: all again). For the
        owner of the bus: it applies to every listener of the bus."""
        bus = self._bus()
        ids = None if cob_ids is None else _cob_ids(cob_ids)
        with self._lock:
            self.accepted = ids
            if bus is not None:
                bus.set_filters(None if ids is None else
                                [{"can_id": c, "can_mask": 0x7FF, "extended": False}
                                 for c in sorted(ids)])
            self._update()

    def reinstall(self) -> None:
        """Filter again in the kernel: the bus's socket is new (it was opened again)."""
        with self._lock:
            self._update()

    def is_own(self, msg: can.Message) -> bool:
        """``msg`` is the echo of a claimed frame (always False on a bus that does not echo)."""
        return (self.echoes and msg.arbitration_id in self.cob_ids and not msg.is_extended_id
                and not msg.is_remote_frame and not msg.is_error_frame)

    def _update(self) -> None:
        dead = [key for key, ref in self._owners.items() if ref is not None and ref() is None]
        for key in dead:
            self._claims.pop(key, None)
            self._owners.pop(key, None)
        self.cob_ids = frozenset().union(*self._claims.values())
        bus = self._bus()
        if bus is None or not echoes_own_frames(bus):
            return  # socketcan filters in its kernel already; the others have no socket
        self.in_kernel = _install(bus, self.cob_ids, self.accepted)


def _weak(owner: object) -> weakref.ref[object] | None:
    try:
        return weakref.ref(owner)
    except TypeError:
        return None


receive_filter = PerBus(ReceiveFilter)
"""``receive_filter(bus)``: the one :class:`ReceiveFilter` of ``bus`` (every user of the bus
shares it)."""


def refresh(bus: can.BusABC) -> None:
    """Put the bus's kernel filter on its socket again (a bus opened again has a new one)."""
    found = receive_filter.get(bus)
    if found is not None:
        found.reinstall()


class OwnFrameGate(can.Listener):
    """Passes every frame to ``listener`` except the echoes of the bus's own frames."""

    def __init__(self, listener: can.Listener, own: ReceiveFilter) -> None:
        self.listener = listener
        self.own = own
        self.dropped = 0

    def on_message_received(self, msg: can.Message) -> None:
        if self.own.is_own(msg):
            self.dropped += 1
            return
        self.listener.on_message_received(msg)

    def on_error(self, exc: Exception) -> None:
        self.listener.on_error(exc)

    def stop(self) -> None:
        self.listener.stop()


# --- the kernel filter (udp_multicast on Linux) ------------------------------------------

_LD_B, _LD_H, _JEQ, _JGE, _JGT, _RET, _TAX, _TXA = 0x30, 0x28, 0x15, 0x35, 0x25, 0x06, 0x07, 0x87
_JA = 0x05
_ACCEPT, _DROP = 0xFFFF_FFFF, 0
_KEYS = {"timestamp": b"\xa9timestamp", "arbitration_id": b"\xaearbitration_id",
         "is_extended_id": b"\xaeis_extended_id", "is_remote_frame": b"\xafis_remote_frame",
         "is_error_frame": b"\xaeis_error_frame"}
_FALSE = 0xC2


def layout_known() -> bool:
    """python-can's udp_multicast datagrams start as the filter expects: a map whose first
    entries are the float timestamp, the arbitration id and the three flags, in this order."""
    try:
        from can.interfaces.udp_multicast.utils import pack_message
    except ImportError:  # pragma: no cover
        return False
    for arbitration_id, header in ((0x05, b"\x05"), (0x81, b"\xcc\x81"),
                                   (0x181, b"\xcd\x01\x81")):
        probe = pack_message(can.Message(arbitration_id=arbitration_id, is_extended_id=False))
        expected = (b"\x8b" + _KEYS["timestamp"] + b"\xcb" + bytes(8) + _KEYS["arbitration_id"]
                    + header + _KEYS["is_extended_id"] + b"\xc2" + _KEYS["is_remote_frame"]
                    + b"\xc2" + _KEYS["is_error_frame"] + b"\xc2")
        if not probe.startswith(expected):
            return False
    return True


class _Program:
    """Classic BPF instructions whose jumps may name labels (resolved by :meth:`assemble`)."""

    def __init__(self) -> None:
        self.code: list[tuple[int, int | str, int | str, int | str]] = []
        self.labels: dict[str, int] = {}

    def op(self, code: int, k: int | str = 0, jt: int | str = 0, jf: int | str = 0) -> None:
        self.code.append((code, jt, jf, k))

    def label(self, name: str) -> None:
        self.labels[name] = len(self.code)

    def assemble(self) -> list[bytes]:
        out = []
        for at, (code, jt, jf, k) in enumerate(self.code):
            jt, jf, k = (self.labels[v] - at - 1 if isinstance(v, str) else v
                         for v in (jt, jf, k))
            if not (0 <= jt <= 255 and 0 <= jf <= 255):
                raise ValueError("a conditional jump of the filter is out of reach")
            out.append(struct.pack("HBBI", code, jt, jf, k))
        return out


def _ranges(cob_ids: Iterable[int]) -> list[tuple[int, int]]:
    out: list[list[int]] = []
    for c in sorted(cob_ids):
        if out and c == out[-1][1] + 1:
            out[-1][1] = c
        else:
            out.append([c, c])
    return [(lo, hi) for lo, hi in out]


def compile_filter(drop: Iterable[int], accept: Iterable[int] | None = None) -> list[bytes]:
    """A classic BPF program for python-can udp_multicast datagrams: an 11-bit data frame
    whose COB-ID is in ``drop``, or not in ``accept`` (when given), is dropped; every other
    datagram passes."""
    p = _Program()
    at_id = 1 + len(_KEYS["timestamp"]) + 9 + len(_KEYS["arbitration_id"])
    # The layout: map of 11, "timestamp": float64, "arbitration_id": ...; else pass.
    for offset, byte in ((0, 0x8B), (1 + len(_KEYS["timestamp"]), 0xCB),
                         (at_id - len(_KEYS["arbitration_id"]), _KEYS["arbitration_id"][0])):
        p.op(_LD_B, _UDP_HEADER + offset)
        p.op(_JEQ, byte, 0, "pass")
    # The id as a uint16 (0xCD), a uint8 (0xCC) or a positive fixint; else (29 bits) pass.
    p.op(_LD_B, _UDP_HEADER + at_id)
    p.op(_JEQ, 0xCD, 0, "not16")
    _load_id(p, _LD_H, at_id + 1, at_id + 3)
    p.label("not16")
    p.op(_JEQ, 0xCC, 0, "not8")
    _load_id(p, _LD_B, at_id + 1, at_id + 2)
    p.label("not8")
    p.op(_JGE, 0x80, "pass", 0)
    _load_id(p, _LD_B, at_id, at_id + 1)
    p.label("pass")  # near every conditional jump to it: they reach 255 instructions only
    p.op(_RET, _ACCEPT)
    p.label("check")
    for lo, hi in _ranges(drop):
        if lo == hi:
            p.op(_JEQ, lo, 0, 1)
        else:
            p.op(_JGE, lo, 0, 2)
            p.op(_JGT, hi, 1, 0)
        p.op(_RET, _DROP)
    if accept is not None:
        for lo, hi in _ranges(accept):
            if lo == hi:
                p.op(_JEQ, lo, 0, 1)
            else:
                p.op(_JGE, lo, 0, 2)
                p.op(_JGT, hi, 1, 0)
            p.op(_JA, "accept")
        p.op(_RET, _DROP)
    p.label("accept")
    p.op(_RET, _ACCEPT)
    return p.assemble()


def _load_id(p: _Program, load: int, value_at: int, flags_at: int) -> None:
    """X = the id; pass unless the three flags after it (extended, remote, error) are false;
    then A = the id and on to the check."""
    p.op(load, _UDP_HEADER + value_at)
    p.op(_TAX)
    at = flags_at
    for key in ("is_extended_id", "is_remote_frame", "is_error_frame"):
        at += len(_KEYS[key])
        p.op(_LD_B, _UDP_HEADER + at)
        p.op(_JEQ, _FALSE, 0, "pass")
        at += 1
    p.op(_TXA)
    p.op(_JA, "check")


_LAYOUT_KNOWN: bool | None = None


def _install(bus: can.BusABC, drop: frozenset[int], accept: frozenset[int] | None) -> bool:
    """Put the filter on the bus's socket (none when it would pass everything); True if the
    kernel now filters."""
    global _LAYOUT_KNOWN
    if not sys.platform.startswith("linux"):
        return False
    if _LAYOUT_KNOWN is None:
        _LAYOUT_KNOWN = layout_known()
        if not _LAYOUT_KNOWN:
            logger.info("python-can's udp_multicast layout is not the one the kernel filter "
                        "reads: frames are dropped in user space")
    try:
        fd = bus.fileno()
    except (NotImplementedError, OSError):
        return False
    if fd < 0:
        return False
    sock = socket.socket(fileno=os.dup(fd))
    try:
        if (not drop and accept is None) or not _LAYOUT_KNOWN:
            with contextlib.suppress(OSError):  # OSError: none was attached
                sock.setsockopt(socket.SOL_SOCKET, SO_DETACH_FILTER, 0)
            return False
        program = compile_filter(drop, accept)
        if len(program) > BPF_MAXINSNS:
            return False
        code = ctypes.create_string_buffer(b"".join(program))
        sock.setsockopt(socket.SOL_SOCKET, SO_ATTACH_FILTER,
                        struct.pack("HL", len(program), ctypes.addressof(code)))
        return True
    except OSError as err:
        logger.info("no kernel receive filter (%s): frames are dropped in user space", err)
        return False
    finally:
        sock.close()
