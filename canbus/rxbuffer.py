"""The socket receive buffer a command asks for on a socket bus (``--rcvbuf``)."""

from __future__ import annotations

import contextlib
import os
import socket
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import can

DEFAULT_RCVBUF = 4 * 1024 * 1024
"""The socket receive buffer the commands ask for (``--rcvbuf``): about 200 ms of
udp_multicast frames at 20,000 frames/s."""


def enlarge_receive_buffer(bus: can.BusABC, size: int) -> int | None:
    """Ask the kernel for a ``size``-byte receive buffer on a socket bus; the size granted.

    At 20,000 frames/s Linux's default (net.core.rmem_default, 208 KiB, about 12 ms of
    udp_multicast datagrams) overflows whenever the receive thread waits for the GIL a
    little longer, and the kernel drops frames. candump's ``-r`` does the same for
    SocketCAN. The grant is capped by net.core.rmem_max (Linux doubles the value asked).
    None when the bus is not a socket.
    """
    try:
        fd = bus.fileno()
    except (NotImplementedError, AttributeError, OSError, ValueError):
        return None
    if not isinstance(fd, int) or fd < 0:
        return None
    try:
        sock = socket.socket(fileno=os.dup(fd))
    except OSError:
        return None
    with contextlib.closing(sock):
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)
            return int(sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))
        except OSError:
            return None
