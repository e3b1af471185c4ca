"""What ``skin sniff`` and ``skin view`` are told about the bus: ``--config HOST.toml`` (who
sends which PDO) and ``--ask-by-sdo`` (leave to ask the nodes themselves).

Without either, a PDO is attributed to a node only by what the bus shows
(:mod:`canbus.tools.attribution`); the others are named as unattributed, never decoded as
somebody else's.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import can

    from canbus.master.hostconfig import HostConfig
    from canbus.tools.attribution import Attribution, KnownNode
    from canbus.tools.pdo_query import PdoAsker


def add_config_arguments(parser: argparse.ArgumentParser, *, config: bool = True) -> None:
    if config:
        parser.add_argument("--config", metavar="HOST.toml",
                            help="the host config of this bus: which node sends which PDO "
                                 "(patches, force nodes and their force_cob_ids, "
                                 "other_nodes), and its [bus] when no -i is given")
    parser.add_argument("--ask-by-sdo", action="store_true",
                        help="transmit: ask each node whose heartbeat runs and whose PDOs "
                             "are not known for its PDO COB-IDs and mappings by SDO reads "
                             "(default: listen only)")


def tool_config(args: argparse.Namespace) -> HostConfig | None:
    """The host config ``--config`` names (checked), or None."""
    if not getattr(args, "config", None):
        return None
    from canbus.master.hostconfig import load_host_config

    return load_host_config(args.config)


def config_nodes(config: HostConfig | None, args: argparse.Namespace) -> list[KnownNode]:
    """The nodes ``config`` places on the bus the command reads: with several buses, the one
    whose interface and channel the command opened (all of them when none matches)."""
    if config is None:
        return []
    from skin.commands.common.known_nodes import known_nodes

    return known_nodes(config, bus=_bus_name(config, args))


def _bus_name(config: HostConfig, args: argparse.Namespace) -> str | None:
    if len(config.buses) == 1:
        return None
    interface, channel = getattr(args, "interface", None), getattr(args, "channel", None)
    for bus in config.buses:
        if bus.interface == interface and str(bus.channel) == str(channel):
            return bus.name
    return None


def asking(bus: can.BusABC, attribution: Attribution, args: argparse.Namespace,
           wanted: Any = None) -> PdoAsker | None:
    """The SDO asker ``--ask-by-sdo`` allows (its listener goes on the bus's notifier)."""
    if not getattr(args, "ask_by_sdo", False):
        return None
    from canbus.tools.pdo_query import PdoAsker

    if wanted is None:
        return PdoAsker(bus, attribution)
    return PdoAsker(bus, attribution, wanted=wanted)
