"""Bus flags the commands share, beyond python-can's own (``can.cli.add_bus_arguments``)."""

from __future__ import annotations

import argparse

from skin.commands.common import argtypes

DEFAULT_CHANNELS = {"virtual": "skin", "timed": "skin", "udp_multicast": "239.74.163.2"}
"""The channel every command uses when none is given (and python-can's configuration names
none for the interface: ``skin.commands.busopen``), so that they meet on the same bus
without ``-c`` (udp_multicast: python-can's IPv4 default group)."""


def add_rcvbuf_argument(parser: argparse.ArgumentParser) -> None:
    from canbus.rxbuffer import DEFAULT_RCVBUF

    parser.add_argument("--rcvbuf", type=argtypes.rcvbuf, default=DEFAULT_RCVBUF, metavar="BYTES",
                        help="socket receive buffer to ask for on socket buses (udp_multicast, "
                             "socketcan); 0 keeps the system's (default "
                             f"{DEFAULT_RCVBUF >> 20} MiB)")

