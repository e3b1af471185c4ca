"""Open the bus python-can's command-line flags name, in one clear line when it fails.

:func:`open_bus` replaces ``can.cli.create_bus_from_namespace``, which wraps every
failure in an ``argparse.ArgumentError`` listing the whole namespace: the flags are
checked first (a udp_multicast channel must be a multicast group address, a port in
1..65535) and the bus is opened by :func:`canbus.busopen.open_can_bus` (the failure one
``BusError``), python-can's own log lines held back meanwhile
(:func:`skin.commands.common.logs.held_back`).
"""

from __future__ import annotations

import argparse
import ipaddress
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import can

_KEYWORDS = ("channel", "interface", "bitrate", "fd", "data_bitrate", "can_filters",
             "timing", "bus_kwargs")


def bus_kwargs(args: argparse.Namespace, **extra: Any) -> dict[str, Any]:
    """The keyword arguments of ``can.Bus`` the flags give (as python-can collects them)."""
    config: dict[str, Any] = {"single_handle": True, **extra}
    for keyword in _KEYWORDS:
        if keyword in args:
            value = getattr(args, keyword)
            if keyword == "bus_kwargs":
                config.update(value or {})
            else:
                config[keyword] = value
    return config


def check_bus_kwargs(config: dict[str, Any]) -> None:
    """ConfigError for flags no bus could open with, naming the flag."""
    from skin.errors import ConfigError

    interface = config.get("interface")
    channel = config.get("channel")
    if interface == "udp_multicast" and channel is not None:
        try:
            group = ipaddress.ip_address(str(channel))
        except ValueError:
            group = None
        if group is None or not group.is_multicast:
            raise ConfigError("--channel", f"{channel!r} is not a multicast group address "
                              "(udp_multicast: e.g. 239.74.163.2 or ff15:7079:7468:6f6e:6465:"
                              "6d6f:6d63:6173)")
    port = config.get("port")
    if port is not None and (isinstance(port, bool) or not isinstance(port, int)
                             or not 1 <= port <= 65535):
        raise ConfigError("--bus-kwargs port", f"must be a port in 1..65535, got {port!r}")


def describe(config: dict[str, Any]) -> str:
    return f"the bus {config.get('interface', '?')}:{config.get('channel', '?')}"


def open_bus(args: argparse.Namespace, **extra: Any) -> can.BusABC:
    """The bus of the command-line flags; ConfigError or BusError in one line."""
    from canbus.busopen import open_can_bus
    from skin.commands.common.logs import held_back

    config = bus_kwargs(args, **extra)
    check_bus_kwargs(config)
    with held_back("can"):  # a missing driver's warnings, a half-built bus's complaint
        return open_can_bus(config, describe(config))
