"""The buses of a host: ``[bus]`` (one) or ``[[buses]]`` (several, by name) in its config.

A bus table names a python-can interface and how to open it::

    [bus]                      # or [[buses]] with a name each
    interface = "socketcan"    # any python-can interface: socketcan, timed, udp_multicast ...
    channel = "can0"
    bitrate = 1000000
    fd = false                 # CAN FD: patches answer SYNC in one frame, forces go in one
    data_bitrate = 5000000     # the FD data phase (with fd = true)
    options = { port = 43114 } # more keyword arguments for can.Bus, as python-can names them

Command-line bus flags (python-can's own ``-i -c -b --fd --data_bitrate --bus-kwargs``)
override the one bus of a config; a config with several buses takes none.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import can

from canbus.busopen import configured_bus, configured_interface, open_can_bus
from skin.errors import BusError, ConfigError
from skin.inputs import fields

DEFAULT_BUS = "default"
_KEYS = ("name", "interface", "channel", "bitrate", "fd", "data_bitrate", "options")


@dataclass(frozen=True)
class BusConfig:
    """One bus of the host; ``interface`` None: python-can's configuration decides."""

    name: str = DEFAULT_BUS
    interface: str | None = None
    channel: str | int | None = None
    bitrate: int | None = None
    fd: bool = False
    data_bitrate: int | None = None
    options: Mapping[str, Any] = field(default_factory=dict)

    @property
    def described(self) -> str:
        """``interface:channel`` for messages; what python-can's own configuration names
        where the config sets neither (said so), ``?`` for what nothing names."""
        interface, channel = self.interface, self.channel
        if interface is not None:
            return f"{interface}:{'?' if channel is None else channel}"
        configured = configured_bus()
        interface = configured.get("interface")
        if channel is None:
            channel = configured.get("channel")
        named = f"{interface or '?'}:{'?' if channel is None else channel}"
        return f"{named} (python-can's configuration)" if interface else named

    def kwargs(self) -> dict[str, Any]:
        """The keyword arguments of ``can.Bus`` for this bus."""
        out: dict[str, Any] = dict(self.options)
        for key in ("interface", "channel", "bitrate", "data_bitrate"):
            value = getattr(self, key)
            if value is not None:
                out[key] = value
        if self.fd:
            out["fd"] = True
        return out


def buses_from_dict(data: Mapping[str, Any]) -> tuple[BusConfig, ...]:
    """The ``[bus]`` or ``[[buses]]`` tables of a parsed config (none: one default bus)."""
    if "bus" in data and "buses" in data:
        raise ConfigError("buses", "give either [bus] (one bus) or [[buses]] (several), not both")
    if "bus" in data:
        table = data["bus"]
        if not isinstance(table, dict):
            raise ConfigError("bus", "must be a table ([bus])")
        if "name" in table:
            raise ConfigError("bus.name", "the one bus needs no name; [[buses]] tables have one")
        return (_bus(table, "bus", DEFAULT_BUS),)
    if "buses" in data:
        tables = data["buses"]
        if not isinstance(tables, list) or not tables or \
                not all(isinstance(t, dict) for t in tables):
            raise ConfigError("buses", "list the buses as [[buses]] tables")
        buses = []
        for i, table in enumerate(tables):
            if "name" not in table:
                raise ConfigError(f"buses[{i}].name", "missing")
            buses.append(_bus(table, f"buses[{i}]", None))
        check_buses(tuple(buses))
        return tuple(buses)
    return (BusConfig(),)


def _bus(table: Mapping[str, Any], where: str, name: str | None) -> BusConfig:
    fields.known_keys(table, _KEYS, where)
    kwargs: dict[str, Any] = {}
    for key in ("name", "interface"):
        if key in table and (key != "name" or name is None):
            kwargs[key] = fields.text(table[key], f"{where}.{key}", 256)
    for key, kind in (("bitrate", int), ("data_bitrate", int), ("fd", bool)):
        if key in table:
            kwargs[key] = fields.typed(table[key], kind, f"{where}.{key}")
    if "channel" in table:
        channel = table["channel"]
        if not isinstance(channel, str | int) or isinstance(channel, bool):
            raise ConfigError(f"{where}.channel", f"must be a string or an integer, got "
                              f"{fields.shown(channel)}")
        if isinstance(channel, str):
            fields.text(channel, f"{where}.channel", 256)
        else:
            fields.integer(channel, f"{where}.channel", 0, 0xFFFF)
        kwargs["channel"] = channel
    if "options" in table:
        if not isinstance(table["options"], dict):
            raise ConfigError(f"{where}.options", "must be a table of can.Bus keyword arguments")
        kwargs["options"] = dict(table["options"])
        for key, value in kwargs["options"].items():
            if not key.isidentifier():
                raise ConfigError(f"{where}.options.{key}", "is not a keyword argument name")
            if not isinstance(value, str | int | float | bool):
                raise ConfigError(f"{where}.options.{key}", "must be a string, a number or "
                                  f"a boolean, got {fields.shown(value)}")
    bus = BusConfig(**kwargs)
    check_bus(bus, where)
    return bus


def check_bus(bus: BusConfig, where: str) -> None:
    if not bus.name or not bus.name.replace("-", "").replace("_", "").isalnum():
        raise ConfigError(f"{where}.name", f"{bus.name!r}: use letters, digits, '-' and '_'")
    for key in ("bitrate", "data_bitrate"):
        value = getattr(bus, key)
        if value is not None and not (isinstance(value, int) and 0 < value <= 20_000_000):
            raise ConfigError(f"{where}.{key}", f"must be a positive bit rate, got {value!r}")
    if bus.interface is not None and bus.interface not in can.VALID_INTERFACES:
        raise ConfigError(f"{where}.interface", f"unknown python-can interface "
                          f"{bus.interface!r}; known: {', '.join(sorted(can.VALID_INTERFACES))}")
    if bus.interface == "udp_multicast" and bus.channel is not None and \
            not _multicast(bus.channel):
        raise ConfigError(f"{where}.channel", f"{bus.channel!r} is not a multicast group "
                          "address (udp_multicast: e.g. 239.74.163.2)")
    if bus.data_bitrate is not None and not bus.fd:
        raise ConfigError(f"{where}.data_bitrate", "is the CAN FD data phase: set fd = true")
    if "fd" in bus.options or any(k in bus.options for k in ("bitrate", "data_bitrate")):
        raise ConfigError(f"{where}.options", "bitrate, data_bitrate and fd have keys of "
                          "their own")


def _multicast(channel: object) -> bool:
    try:
        return ipaddress.ip_address(str(channel)).is_multicast
    except ValueError:
        return False


def check_buses(buses: tuple[BusConfig, ...]) -> None:
    names: set[str] = set()
    for i, bus in enumerate(buses):
        if bus.name in names:
            raise ConfigError(f"buses[{i}].name", f"{bus.name!r} is also an earlier bus")
        names.add(bus.name)


def with_flags(bus: BusConfig, flags: Mapping[str, Any]) -> BusConfig:
    """``bus`` with the command line's bus flags over it (python-can's names: interface,
    channel, bitrate, fd, data_bitrate, and can.Bus keyword arguments)."""
    changes: dict[str, Any] = {}
    options = dict(bus.options)
    for key, value in flags.items():
        if value is None:
            continue
        if key in ("interface", "channel", "bitrate", "data_bitrate"):
            changes[key] = value
        elif key == "fd":
            changes["fd"] = bool(value)
        else:
            options[key] = value
    merged = replace(bus, **changes, options=options)
    check_bus(merged, "bus")
    return merged


BUS_WAYS = ("give one on the command line (-i IFACE -c CHANNEL, e.g. -i socketcan -c can0), "
            "in the config's [bus] table (interface = ..., channel = ...), or in python-can's "
            "configuration (~/.canrc, $CAN_INTERFACE)")
"""The three ways to name a bus, for the one line that says none was given."""


def open_bus(bus: BusConfig) -> can.BusABC:
    """Open ``bus`` with python-can; a :class:`~skin.errors.BusError` naming it if that fails."""
    if bus.interface is None and configured_interface() is None:
        raise BusError(f"bus {bus.name!r} has no interface: {BUS_WAYS}")
    what = f"the bus {bus.described}" if bus.name == DEFAULT_BUS else \
        f"bus {bus.name!r} ({bus.described})"
    return open_can_bus(bus.kwargs(), what)
