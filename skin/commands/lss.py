"""``skin lss``: patches by identity (LSS, CiA 305).

* ``skin lss scan [--json F]``: every node on the bus with its identity (vendor, product,
  revision, serial of 0x1018): configured nodes by SDO, nodes waiting for LSS (node-ID
  0xFF) by a fastscan walk that configures nothing (``canbus.master.lss_scan``);
* ``skin lss assign SERIAL NODE_ID [--store]``: the patch with that serial number gets
  the node-ID (and keeps it across power cycles with ``--store``).

Bus flags are python-can's (``-i``, ``-c``, ``--bus-kwargs``), defaults as every command.
"""

from __future__ import annotations

import argparse
import json
from typing import Any


def _network(args: argparse.Namespace) -> Any:
    import canopen

    from skin.commands.common.busopen import open_command_bus

    bus, _ = open_command_bus(args, command="skin lss", sends=True)
    network = canopen.Network(bus)
    network.NOTIFIER_CYCLE = 0.05
    network.connect()
    return network


def _scan(args: argparse.Namespace) -> int:
    from canbus.master.lss_scan import lss_scan
    from skin.atomic import atomic_write

    network = _network(args)
    try:
        found = lss_scan(network, timeout_s=args.timeout, thorough=args.thorough,
                         scan_s=args.scan_s)
    finally:
        network.disconnect()
    for node in found:
        i = node.identity
        where = f"node {node.node_id:3d}" if node.node_id is not None else "waiting "
        print(f"{where}  {i.kind:8s} vendor 0x{i.vendor:08X} product 0x{i.product:08X} "
              f"revision 0x{i.revision:08X} serial 0x{i.serial:08X}")
    waiting = sum(not n.configured for n in found)
    print(f"{len(found)} nodes: {len(found) - waiting} configured, {waiting} waiting for LSS")
    if args.json:
        with atomic_write(args.json) as handle:
            handle.write(json.dumps({"nodes": [n.as_dict() for n in found]}, indent=2)
                         .encode() + b"\n")
    return 0


def _assign(args: argparse.Namespace) -> int:
    from canbus.master.lss_assign import assign

    network = _network(args)
    try:
        done = assign(network, args.serial, args.node_id, store=args.store)
    finally:
        network.disconnect()
    was = "waited for LSS" if done.previous is None else f"was node {done.previous}"
    print(f"patch 0x{done.serial:08X} ({was}) -> node {done.node_id}"
          f"{', stored' if done.stored else ''}")
    return 0


def add_subparser(subparsers: Any) -> None:
    from skin.commands.common import argtypes

    step_s = argtypes.number("timeout", above=0.0, high=60.0, unit="s")
    scan_s = argtypes.number("scan time", above=0.0, high=600.0, unit="s")

    parser = subparsers.add_parser("lss", help="patches by identity: scan, assign node-IDs "
                                               "(LSS, CiA 305)")
    group = parser.add_subparsers(title="lss commands", metavar="ACTION", required=True)
    scan = group.add_parser("scan", help="list the nodes on the bus by identity, configured "
                                         "or waiting for LSS")
    scan.add_argument("--json", type=argtypes.output_file, metavar="FILE",
                      help="write the list as JSON")
    scan.add_argument("--timeout", type=step_s, default=0.1, metavar="S",
                      help="how long a fastscan step waits for an answer (default 0.1 s)")
    scan.add_argument("--thorough", action="store_true",
                      help="walk every vendor, product and revision, not only canskin "
                           "patches'")
    scan.add_argument("--scan-s", type=scan_s, default=0.3, metavar="S",
                      help="how long the SDO scan of configured nodes waits (default 0.3 s)")
    argtypes.add_bus_arguments(scan)
    scan.set_defaults(func=_scan)
    assign = group.add_parser("assign", help="give the patch with a serial number a node-ID")
    assign.add_argument("serial", type=argtypes.serial, metavar="SERIAL",
                        help="its serial number (0x1018 sub 4; decimal or 0x hex)")
    assign.add_argument("node_id", type=argtypes.node_id, metavar="NODE_ID", help="1..127")
    assign.add_argument("--store", action="store_true",
                        help="LSS store configuration: the patch keeps the node-ID across "
                             "power cycles")
    argtypes.add_bus_arguments(assign)
    assign.set_defaults(func=_assign)


