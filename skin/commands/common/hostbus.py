"""The buses a host command opens: the config's ``[bus]`` / ``[[buses]]`` with python-can's
command-line bus flags over the one bus, the same defaults every command uses, and one
clear line when there is no bus at all."""

from __future__ import annotations

import argparse
import logging
from contextlib import ExitStack
from dataclasses import replace
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import can

    from canbus.busio import ResilientBus
    from canbus.master.busconfig import BusConfig
    from canbus.master.hostconfig import HostConfig

logger = logging.getLogger("skin.commands")

_FLAGS = ("interface", "channel", "bitrate", "fd", "data_bitrate", "timing")


def bus_flags(args: argparse.Namespace) -> dict[str, Any]:
    """The bus flags given on the command line (python-can's names)."""
    flags = {key: getattr(args, key) for key in _FLAGS if key in args}
    flags.update(getattr(args, "bus_kwargs", None) or {})
    return flags


def resolve(config: HostConfig, args: argparse.Namespace) -> HostConfig:
    """``config`` with the command line's bus flags over its one bus and the commands'
    default channel; ConfigError for flags given to a config with several buses, BusError
    when no interface is named anywhere."""
    from canbus.busopen import configured_interface
    from canbus.master.busconfig import BUS_WAYS, with_flags
    from skin.errors import BusError, ConfigError

    flags = bus_flags(args)
    if len(config.buses) > 1:
        if flags:
            raise ConfigError("bus flags", f"{config.source} has {len(config.buses)} buses "
                              "([[buses]]): set each one in its table, not on the command "
                              "line")
        return config
    bus = with_flags(config.buses[0], flags)
    if bus.interface is None and configured_interface() is None:
        raise BusError(f"no bus: {config.source} names none; {BUS_WAYS}")
    if bus.channel is None and bus.interface is not None:
        from skin.commands.common.busopen import default_channel_for

        channel = default_channel_for(bus.interface)  # python-can's, else canskin's
        if channel is not None:
            bus = replace(bus, channel=channel)
    _warn_if_in_process(bus.interface, flags, config.source)
    return replace(config, buses=(bus,))


def _warn_if_in_process(interface: str | None, flags: dict[str, Any], source: str) -> None:
    """A warning when the one bus is inside this process and the command line did not ask
    for it: it came from the config or python-can's configuration, where a bus meant to meet
    patches in another process is easily left."""
    from canbus.busopen import configured_interface

    if flags.get("interface") is not None:
        return  # -i virtual: the user's own choice, said on the command line
    where = source if interface is not None else "python-can's configuration"
    interface = interface if interface is not None else configured_interface()
    if interface in ("virtual", "timed"):
        logger.warning("the bus %s (from %s) reaches only this process; use udp_multicast "
                       "to meet patches in another process", interface, where)


def open_all(config: HostConfig, stack: ExitStack, *,
             rcvbuf: int = 0) -> dict[str, can.BusABC]:
    """Open every bus of ``config`` (:func:`open_resilient`); each is shut down when
    ``stack`` closes."""
    opened: dict[str, can.BusABC] = {}
    for bus in config.buses:
        handle = open_resilient(bus, rcvbuf, name=f"{bus.name} ({bus.described})")
        stack.callback(handle.shutdown)
        opened[bus.name] = handle
    return opened


def open_resilient(bus: BusConfig, rcvbuf: int, *, name: str) -> ResilientBus:
    """``bus`` as a ``canbus.busio.ResilientBus`` (opened again when it keeps failing;
    ``rcvbuf``: its socket's receive buffer, each time), python-can's log lines held back."""
    from functools import partial

    from canbus.busio import ResilientBus
    from canbus.master.busconfig import open_bus
    from canbus.rxbuffer import enlarge_receive_buffer
    from skin.commands.common.logs import held_back

    with held_back("can"):
        return ResilientBus(partial(open_bus, bus), name=name,
                            prepare=partial(enlarge_receive_buffer, size=rcvbuf)
                            if rcvbuf else None)


def describe(config: HostConfig) -> str:
    """``interface:channel`` of each bus, for messages."""
    if len(config.buses) == 1:
        return config.buses[0].described
    return ", ".join(f"{b.name} ({b.described})" for b in config.buses)
