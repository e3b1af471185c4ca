"""Ports and multicast groups for tests and rigs: one allocator, unique on the machine.

Every UDP port, multicast group and TCP port a test or a rig opens comes from here
(``tests/test_suite_rules.py`` checks that no test or rig spells one out). A process takes
a block of :data:`BLOCK` ports below the kernel's ephemeral range (read from
``/proc/sys/net/ipv4/ip_local_port_range``) by holding an exclusive ``flock`` on the
block's file in the temporary folder; the kernel drops the lock when the process ends,
however it ends. So two suites run at once (or two pytest-xdist workers) never share a
port or a group, and no port can be one the kernel hands out to a client socket. Inside
its block a process counts up; a full block takes the next free one.

A multicast group goes with its port (``udp_bus``): Linux hands a socket every datagram to
its port from any group joined on the machine, so the port is what keeps buses apart; the
group is unique too. Where the interface can pick its own port and say which (a TCP
listener we own), use port 0 instead; Zenoh cannot say which port it took, so its
endpoints take :func:`tcp_port`.

    group, port = udp_bus()            # python-can udp_multicast: channel=group, port=port
    endpoint = f"tcp/127.0.0.1:{tcp_port()}"
"""

from __future__ import annotations

import fcntl
import ipaddress
import os
import socket
import tempfile
import threading
from pathlib import Path

FIRST = 20000
"""The lowest port handed out (above the well-known and registered services people run)."""
BLOCK = 256
"""Ports per block: a whole suite uses fewer; one more block is taken if it does not."""
GROUP_BASE = int(ipaddress.IPv4Address("239.74.0.0"))  # organisation-local scope (RFC 2365)
LOCK_DIR = Path(tempfile.gettempdir()) / "canskin-ports"

_lock = threading.Lock()
_held: list[int] = []  # lock files of the blocks this process holds (open while it lives)
_taken: set[int] = set()
_block = -1
_next = 0


def ephemeral_start() -> int:
    """The first port of the kernel's ephemeral range (32768 where it cannot be read)."""
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


def _blocks() -> int:
    count = (ephemeral_start() - FIRST) // BLOCK
    if count < 1:
        raise RuntimeError(f"no room for test ports between {FIRST} and the ephemeral range "
                           f"starting at {ephemeral_start()}")
    return count


def _take_block(after: int) -> int:
    """Hold the first free block after ``after``; its lock lives as long as this process."""
    LOCK_DIR.mkdir(mode=0o777, exist_ok=True)
    count = _blocks()
    start = os.getpid() % count if after < 0 else after + 1  # spread the first blocks
    for k in range(count):
        block = (start + k) % count
        if block in _taken:
            continue
        fd = os.open(LOCK_DIR / f"block-{block}", os.O_RDONLY | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        _held.append(fd)
        _taken.add(block)
        return block
    raise RuntimeError(f"all {count} port blocks under {LOCK_DIR} are held by other processes")


def _allocate() -> int:
    """The next unused slot (block * BLOCK + k) of this process."""
    global _block, _next
    with _lock:
        if _block < 0 or _next == BLOCK:
            _block, _next = _take_block(_block), 0
        slot = _block * BLOCK + _next
        _next += 1
        return slot


def udp_bus() -> tuple[str, int]:
    """A multicast group and a UDP port that no other test, here or in another process,
    uses: python-can's ``udp_multicast`` bus on ``channel=group, port=port``."""
    slot = _allocate()
    return str(ipaddress.IPv4Address(GROUP_BASE + slot)), FIRST + slot


def udp_port() -> int:
    """A UDP port of its own (a bus on a group it does not choose, e.g. the default one)."""
    return udp_bus()[1]


def tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port of its own on ``host``, free now (a leftover listener of another program
    is skipped), for a server that cannot listen on port 0 and tell which port it took."""
    while True:
        port = FIRST + _allocate()
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind((host, port))
            except OSError:
                continue
            return port
