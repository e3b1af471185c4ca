"""Bus flags the commands share, beyond python-can's own (``can.cli.add_bus_arguments``)."""

from __future__ import annotations

import argparse


def default_channel(args: argparse.Namespace) -> None:
    """A channel when none was given: ``skin`` on virtual, python-can's default group on
    udp_multicast, so that every command meets on the same bus without ``-c``."""
    from can.interfaces.udp_multicast import UdpMulticastBus

    if not hasattr(args, "channel"):
        args.channel = ("skin" if args.interface == "virtual"
                        else UdpMulticastBus.DEFAULT_GROUP_IPv4)


def add_rcvbuf_argument(parser: argparse.ArgumentParser) -> None:
    from canbus.tools.recorder import DEFAULT_RCVBUF

    parser.add_argument("--rcvbuf", type=int, default=DEFAULT_RCVBUF, metavar="BYTES",
                        help="socket receive buffer to ask for on socket buses (udp_multicast, "
                             "socketcan); 0 keeps the system's (default "
                             f"{DEFAULT_RCVBUF >> 20} MiB)")
