"""Open the bus python-can's command-line flags name, in one clear line when it fails.

:func:`open_bus` replaces ``can.cli.create_bus_from_namespace``, which wraps every
failure in an ``argparse.ArgumentError`` listing the whole namespace: the flags are
checked first (a udp_multicast channel must be a multicast group address, a port in
1..65535) and the bus is opened by :func:`canbus.busopen.open_can_bus` (the failure one
``BusError``), python-can's own log lines held back meanwhile
(:func:`skin.commands.common.logs.held_back`).

Which bus, when the flags do not say (:func:`choose_bus`, one set of defaults for every
command, as ``skin run`` has): the host config's ``[bus]`` table for a command given
``--config HOST.toml`` (``skin sniff``, ``skin view``), else python-can's own configuration
(``$CAN_INTERFACE``, ``$CAN_CHANNEL``, ``$CAN_BITRATE``, ``$CAN_CONFIG``, ``~/.canrc``,
``can.ini``). No interface from any of them is an error that says so: a command never falls
back on a bus inside its own process where a user expects a real one (``skin sniff
--record`` would record an empty bus in silence). A channel left unset is python-can's
configuration's when it names one for the same interface, else canskin's default for
``virtual``, ``timed`` (``skin``) and ``udp_multicast`` (python-can's IPv4 group). The
command says which bus it opened, and that ``virtual`` and ``timed`` reach only its own
process, in the first line of its output (:func:`announce`, on stdout: a failure after it
is still one line on stderr).
"""

from __future__ import annotations

import argparse
import ipaddress
import sys
from typing import TYPE_CHECKING, Any, TextIO

if TYPE_CHECKING:
    import can

    from canbus.master.hostconfig import HostConfig

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


IN_PROCESS = ("virtual", "timed")
"""Interfaces whose bus lives inside one process."""


def python_can_settings() -> dict[str, Any]:
    """What python-can's configuration sets, merged as ``can.util.load_config`` merges it
    (``can.rc``, the environment, the files), without its check that an interface is named
    (``canbus.busopen.configured_bus`` is the bus it names, checked)."""
    import can

    merged: dict[str, Any] = {}
    try:
        sources = (can.rc, can.util.load_environment_config(), can.util.load_file_config())
    except (ValueError, KeyError, OSError) as err:
        from skin.errors import BusError

        raise BusError(f"python-can's configuration is not usable: {err}") from err
    for source in sources:
        for key, value in source.items():
            if key == "bustype":
                key = "interface"
            merged.setdefault(key, can.util.cast_from_string(value)
                              if isinstance(value, str) else value)
    return merged


def choose_bus(args: argparse.Namespace, *, command: str,
               config: HostConfig | None = None) -> str:
    """Fill ``args`` with the bus to open (module docstring); ``interface:channel (from
    where)``. :class:`~skin.errors.BusError` when nothing names an interface."""
    from skin.errors import BusError

    configured = python_can_settings()
    if getattr(args, "interface", None):
        source = "-i"
    elif config is not None and len(config.buses) == 1 and config.buses[0].interface:
        _from_config(args, config)
        source = f"{config.source} [bus]"
    elif configured.get("interface"):
        args.interface = configured["interface"]
        source = "python-can's configuration"
    else:
        raise BusError(f"{command}: no bus: give -i IFACE [-c CHANNEL] (e.g. -i socketcan -c "
                       "can0, or -i udp_multicast to meet skin sim run and skin run in other "
                       "processes), a host config with a [bus] table (--config), or "
                       "python-can's configuration ($CAN_INTERFACE, ~/.canrc)")
    if getattr(args, "channel", None) is None:
        channel = default_channel_for(args.interface, configured)
        if channel is not None:
            args.channel = channel
    channel = getattr(args, "channel", None)
    return f"{args.interface}:{channel if channel is not None else '(driver default)'} " \
           f"(from {source})"


def default_channel_for(interface: str, configured: dict[str, Any] | None = None) -> Any:
    """The channel of ``interface`` when none is given: python-can's configuration's, if it
    names one for that interface (or for none), else canskin's default (None: the driver's)."""
    from skin.commands.common.busargs import DEFAULT_CHANNELS

    configured = python_can_settings() if configured is None else configured
    if configured.get("channel") is not None and \
            configured.get("interface") in (None, interface):
        return configured["channel"]
    return DEFAULT_CHANNELS.get(interface)


def _from_config(args: argparse.Namespace, config: HostConfig) -> None:
    bus = config.buses[0]
    args.interface = bus.interface
    for key in ("channel", "bitrate", "data_bitrate"):
        if getattr(args, key, None) is None and getattr(bus, key) is not None:
            setattr(args, key, getattr(bus, key))
    if bus.fd and not getattr(args, "fd", False):
        args.fd = True
    if bus.options:
        args.bus_kwargs = {**bus.options, **(getattr(args, "bus_kwargs", None) or {})}


def announce(command: str, described: str, *, sends: bool = False,
             out: TextIO | None = None) -> None:
    """Say which bus ``command`` uses, and that ``virtual`` reaches only this process: one
    line of the command's output (stdout), so that an error after it is still one line on
    stderr."""
    note = ""
    interface = described.split(":", 1)[0]
    if interface in IN_PROCESS:
        verb = "sends to and hears" if sends else "hears"
        note = (f"; note: {interface} is a bus inside this process: it {verb} nothing of "
                "another process (skin sim run, skin run); use -i udp_multicast, or a real "
                "bus (-i socketcan -c can0)")
    print(f"{command}: bus {described}{note}", file=out or sys.stdout, flush=True)


def open_command_bus(args: argparse.Namespace, *, command: str,
                     config: HostConfig | None = None, sends: bool = False,
                     out: TextIO | None = None, resilient: bool = False,
                     rcvbuf: int = 0) -> tuple[Any, str]:
    """:func:`choose_bus`, then the bus (:func:`open_bus`), then :func:`announce`; the bus and
    its description. ``resilient``: a ``canbus.busio.ResilientBus`` (what recv raises is
    survived, a bus that keeps failing is opened again), ``rcvbuf`` its socket's receive
    buffer each time it is opened."""
    from functools import partial

    described = choose_bus(args, command=command, config=config)
    if resilient:
        from canbus.busio import ResilientBus
        from canbus.rxbuffer import enlarge_receive_buffer

        bus: Any = ResilientBus(partial(open_bus, args),
                                name=f"{args.interface}:{getattr(args, 'channel', None)}",
                                prepare=partial(enlarge_receive_buffer, size=rcvbuf)
                                if rcvbuf else None)
    else:
        bus = open_bus(args)  # one line naming the bus when it cannot be opened
    announce(command, described, sends=sends, out=out)  # after: a failure is one line, naming it
    return bus, described
