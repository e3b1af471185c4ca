"""Bus flags the commands share, beyond python-can's own (``can.cli.add_bus_arguments``)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import can

DEFAULT_CHANNELS = {"virtual": "skin", "timed": "skin", "udp_multicast": "239.74.163.2"}
"""The channel every command uses when none is given, so that they meet on the same bus
without ``-c`` (udp_multicast: python-can's IPv4 default group)."""


def default_channel(args: argparse.Namespace) -> None:
    """Set ``args.channel`` to :data:`DEFAULT_CHANNELS`' when none was given; other
    interfaces keep python-can's own default (its configuration, or the driver's)."""
    if not hasattr(args, "channel") and getattr(args, "interface", None) in DEFAULT_CHANNELS:
        args.channel = DEFAULT_CHANNELS[args.interface]


def open_from_namespace(args: argparse.Namespace) -> can.BusABC:
    """python-can's ``create_bus_from_namespace``, a bus it cannot open being a BusError
    (one line) rather than the ``argparse.ArgumentError`` it raises."""
    import can.cli

    from skin.errors import BusError

    try:
        return can.cli.create_bus_from_namespace(args)
    except argparse.ArgumentError as err:
        cause = err.__cause__ or err
        raise BusError(f"cannot open the bus: {type(cause).__name__}: {cause}") from err


def add_rcvbuf_argument(parser: argparse.ArgumentParser) -> None:
    from canbus.tools.recorder import DEFAULT_RCVBUF

    parser.add_argument("--rcvbuf", type=int, default=DEFAULT_RCVBUF, metavar="BYTES",
                        help="socket receive buffer to ask for on socket buses (udp_multicast, "
                             "socketcan); 0 keeps the system's (default "
                             f"{DEFAULT_RCVBUF >> 20} MiB)")


def node_id(text: str) -> int:
    """An argparse type: a CANopen node-ID, 1..127 (decimal or 0x hex)."""
    value = int(text, 0)
    if not 1 <= value <= 127:
        raise argparse.ArgumentTypeError(f"node-ID must be in 1..127, got {text}")
    return value
