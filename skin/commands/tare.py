"""``skin tare NODE``: re-zero a patch through its force node, by SDO, as any master would.

The force node (``eds/skin-forces.eds``) takes a write of 1 to object 0x2007: the host
re-zeroes the patch the node publishes at its last complete sample. The host refuses
(SDO abort 0x08000022) while the patch is loaded or not decoded; the command then says
so in one line and exits 1.
"""

from __future__ import annotations

import argparse
from typing import Any

from skin.commands.common import argtypes

ABORTS = {0x0800_0022: "the patch is loaded, or not operational: unload it and try again",
          0x0609_0030: "the value is not a tare command",
          0x0602_0000: "the node has no tare object: is it a canskin force node?"}


def _tare(args: argparse.Namespace) -> int:
    import canopen
    from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

    from canbus.master.forcenode import TARE, TARE_COMMAND
    from canbus.od import load_od
    from skin.commands.common.busopen import open_command_bus
    from skin.errors import BusError

    bus, described = open_command_bus(args, command="skin tare", sends=True)
    with bus:
        network = canopen.Network(bus)
        network.connect()
        try:
            node = network.add_node(canopen.RemoteNode(args.node,
                                                       load_od("skin-forces", args.node)))
            node.sdo.RESPONSE_TIMEOUT = args.timeout
            try:
                node.sdo.download(TARE, 0, bytes([TARE_COMMAND]))
            except SdoAbortedError as err:
                why = ABORTS.get(err.code, "")
                raise BusError(f"force node {args.node} refused the tare: abort "
                               f"0x{err.code:08X}{': ' + why if why else ''}") from err
            except SdoCommunicationError as err:
                raise BusError(f"force node {args.node} did not answer on {described}: "
                               f"{err}") from err
        finally:
            network.disconnect()
    print(f"force node {args.node}: tared")
    return 0


def add_subparser(subparsers: Any) -> None:


    parser = subparsers.add_parser(
        "tare", help="re-zero a patch through its force node (SDO write of 0x2007)",
        description="Re-zero the patch a force node publishes, by an SDO write of 1 to its "
                    "object 0x2007, as any CANopen master can. Refused while the patch is "
                    "loaded.")
    parser.add_argument("node", type=argtypes.node_id, metavar="NODE",
                        help="the force node's node-ID (a patch's is its node-ID + 64 by "
                             "default)")
    parser.add_argument("--timeout", type=argtypes.seconds, default=1.0, metavar="S",
                        help="SDO response time-out (default 1 s)")
    argtypes.add_bus_arguments(parser)
    parser.set_defaults(func=_tare)
