"""A fault injector for the host's fault tests: what a hostile or broken bus does to it.

- :class:`UdpInjector`: datagrams on a udp_multicast group that python-can cannot unpack,
  error frames it refuses (``could not unpack received message``), and well-formed frames
  of any COB-ID (garbage SDO responses, EMCY floods, NMT commands) at a chosen rate.
- :class:`FaultyBus`: a bus (the timed bus, or python-can's virtual) whose ``recv`` raises
  on command, once or until healed, as a driver does when its interface goes down.
- :class:`GoneBus`: python-can interface ``gone`` for the command line (registered by
  :func:`gone_bus_registered`): a virtual bus that, once :data:`GONE` is set, raises
  ``ENETDOWN`` from ``recv`` and cannot be opened again.
- :func:`stall`: SIGSTOP / SIGCONT a process, as a loaded machine or a debugger does.
"""

from __future__ import annotations

import errno
import os
import random
import signal
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import can
from can.interfaces.udp_multicast.utils import pack_message

ERROR_FRAME_ID = 0x20000004  # SocketCAN's CAN_ERR_FLAG | CAN_ERR_CRTL: not an arbitration id


class UdpInjector:
    """Sends raw datagrams to every python-can udp_multicast bus of ``group``:``port``."""

    def __init__(self, group: str, port: int, *, seed: int = 0) -> None:
        self.address = (group, port)
        self.random = random.Random(seed)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
        self.sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
        self.sent = 0

    def close(self) -> None:
        self.sock.close()

    def send(self, datagram: bytes) -> None:
        self.sock.sendto(datagram, self.address)
        self.sent += 1

    def garbage(self, count: int = 1) -> None:
        """Datagrams python-can cannot unpack: a byte, random bytes after one msgpack never
        uses, a msgpack integer."""
        for k in range(count):
            if k % 3 == 0:
                self.send(b"x")
            elif k % 3 == 1:
                self.send(b"\xc1" + bytes(self.random.getrandbits(8)
                                           for _ in range(self.random.randint(0, 63))))
            else:
                self.send(b"\xcd\x01\x81")  # a msgpack integer: not a frame

    def error_frames(self, count: int = 1) -> None:
        """Error frames as SocketCAN encodes them (the error flag in the id): python-can's
        udp_multicast receiver refuses them with ``CanOperationError``."""
        msg = can.Message(arbitration_id=ERROR_FRAME_ID, is_extended_id=True,
                          is_error_frame=True, data=bytes(8), check=False)
        for _ in range(count):
            self.send(pack_message(msg))

    def frame(self, cob_id: int, data: bytes) -> None:
        self.send(pack_message(can.Message(arbitration_id=cob_id, data=data,
                                           is_extended_id=False, timestamp=time.time())))

    def at_rate(self, per_s: float, count: int, make: Any) -> int:
        """Call ``make(k)`` for k in 0..count-1, ``per_s`` times a second (paced in
        bursts); returns ``count``."""
        started, k = time.monotonic(), 0
        while k < count:
            due = min(count, int((time.monotonic() - started) * per_s) + 1)
            while k < due:
                make(k)
                k += 1
            time.sleep(0.002)
        return k

    def nmt(self, command: int, node_id: int) -> None:
        self.frame(0x000, bytes([command, node_id]))

    def garbled_sdo(self, node_id: int) -> None:
        """An SDO response to ``node_id``'s client that answers nothing it asked."""
        self.frame(0x580 + node_id, bytes(self.random.getrandbits(8) for _ in range(8)))

    def emcy(self, node_id: int, code: int, taxel: int, status: int = 1) -> None:
        self.frame(0x80 + node_id, code.to_bytes(2, "little") + bytes([0x81 if code else 0,
                                                                          taxel, status, 0, 0, 0]))


class FaultyBus(can.BusABC):
    """``inner`` whose ``recv`` raises on command (:meth:`fail_once`, :meth:`fail_always`
    until :meth:`heal`); everything else is ``inner``'s."""

    def __init__(self, inner: can.BusABC) -> None:
        self.inner = inner
        self.channel_info = f"faulty {inner.channel_info}"
        self._can_protocol = inner.protocol
        self._once = False
        self._always = False
        self.raised = 0
        super().__init__(channel="faulty")

    def fail_once(self) -> None:
        self._once = True

    def fail_always(self) -> None:
        self._always = True

    def heal(self) -> None:
        self._always = self._once = False

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if self._once or self._always:
            self._once = False
            self.raised += 1
            raise can.CanOperationError("Network is down") from OSError(errno.ENETDOWN,
                                                                         "Network is down")
        return self.inner.recv(timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self.recv(timeout), True

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.inner.send(msg, timeout)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_") or "inner" not in self.__dict__:
            raise AttributeError(name)
        return getattr(self.inner, name)

    def shutdown(self) -> None:
        super().shutdown()
        self.inner.shutdown()


GONE = threading.Event()
"""Set: every :class:`GoneBus` fails to receive and none can be opened."""


class GoneBus(FaultyBus):
    """python-can interface ``gone``: a virtual bus that is gone for good once
    :data:`GONE` is set (``recv`` raises ENETDOWN, opening raises)."""

    def __init__(self, channel: Any = "gone", **kwargs: Any) -> None:
        if GONE.is_set():
            raise can.CanInitializationError(f"cannot open {channel}: Network is down")
        super().__init__(can.Bus(interface="virtual", channel=channel))

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if GONE.is_set():
            self.raised += 1
            raise can.CanOperationError("Network is down") from OSError(errno.ENETDOWN,
                                                                         "Network is down")
        return self.inner.recv(timeout)


@contextmanager
def gone_bus_registered() -> Iterator[None]:
    """python-can interface ``gone`` (``-i gone``) in this process for the block."""
    import can.interfaces
    import can.util

    modules = (can, can.interfaces, can.util)  # each holds its own VALID_INTERFACES name
    valid = can.VALID_INTERFACES
    can.interfaces.BACKENDS["gone"] = ("tests.canbus.faults", "GoneBus")
    for module in modules:
        module.VALID_INTERFACES = valid | {"gone"}  # type: ignore[attr-defined]
    GONE.clear()
    try:
        yield
    finally:
        GONE.clear()
        can.interfaces.BACKENDS.pop("gone", None)
        for module in modules:
            module.VALID_INTERFACES = valid  # type: ignore[attr-defined]


@contextmanager
def stopped_process(pid: int) -> Iterator[None]:
    """``pid`` stopped (SIGSTOP) for the block, continued (SIGCONT) after it."""
    os.kill(pid, signal.SIGSTOP)
    try:
        yield
    finally:
        os.kill(pid, signal.SIGCONT)


def stall(pid: int, times: int, seconds: float, gap_s: float) -> None:
    """Stop ``pid`` ``times`` times for ``seconds`` each, ``gap_s`` apart."""
    for _ in range(times):
        with stopped_process(pid):
            time.sleep(seconds)
        time.sleep(gap_s)


def rss_bytes(pid: int | None = None) -> int:
    """The resident set size of ``pid`` (default: this process), from /proc."""
    with open(f"/proc/{pid or 'self'}/status", encoding="ascii") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("no VmRSS in /proc")
