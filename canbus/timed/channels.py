"""The timed channels of this process: a registry of wires, joined and left by buses."""

from __future__ import annotations

import threading
from collections.abc import Hashable

from canbus.timed.errors import TimedBusConfigError
from canbus.timed.node import Node
from canbus.timed.wire import Wire

DEFAULT_BITRATE, DEFAULT_DATA_BITRATE = 1_000_000, 5_000_000

_wires: dict[Hashable, Wire] = {}
_wires_lock = threading.Lock()


def open_channels() -> list[Hashable]:
    """Channels with a timed wire in this process (a bus still open on each)."""
    with _wires_lock:
        return list(_wires)


def wire_of(channel: Hashable) -> Wire | None:
    with _wires_lock:
        return _wires.get(channel)


def join(channel: Hashable, *, bitrate: int, data_bitrate: int | None, fd: bool,
         realtime: bool, window_s: float, resolution_s: float,
         **node: object) -> tuple[Wire, Node]:
    """A new node on the channel's wire (created if needed); bitrates and clock must agree.

    ``data_bitrate`` None: the wire's, or 5 Mbit/s for the first CAN FD bus. ``node``: the
    keyword arguments of :meth:`Wire.add_node`. The first bus sets the statistics window and
    the real-time resolution.
    """
    with _wires_lock:
        wire = _wires.get(channel)
        if wire is None:
            if fd and data_bitrate is None:
                data_bitrate = DEFAULT_DATA_BITRATE
            wire = Wire(channel, bitrate, data_bitrate, realtime, window_s, resolution_s)
            _wires[channel] = wire
        else:
            _agree(wire, bitrate, data_bitrate, fd, realtime)
        return wire, wire.add_node(fd=fd, **node)  # type: ignore[arg-type]


def leave(wire: Wire, node: Node) -> None:
    """The node leaves its wire; the last one closes the channel."""
    with _wires_lock:
        last = wire.remove_node(node)
        if last and _wires.get(wire.channel) is wire:
            del _wires[wire.channel]


def close_all() -> list[Hashable]:
    """Close every channel (its buses can no longer send or receive); the channels it closed.

    For test fixtures that must not let one test's forgotten bus run into the next.
    """
    with _wires_lock:
        wires = list(_wires.values())
    for wire in wires:
        for node in list(wire.nodes):
            leave(wire, node)
    return [wire.channel for wire in wires]


def _agree(wire: Wire, bitrate: int, data_bitrate: int | None, fd: bool,
           realtime: bool) -> None:
    channel = wire.channel
    if wire.bitrate != bitrate:
        raise TimedBusConfigError(f"timed channel {channel!r} runs at {wire.bitrate} bit/s; "
                                  f"this bus asked for {bitrate}")
    if wire.realtime != realtime:
        raise TimedBusConfigError(f"timed channel {channel!r} runs "
                                  f"{'in real' if wire.realtime else 'in simulated'} time; "
                                  f"this bus asked for realtime={realtime}")
    if data_bitrate is None and fd and wire.data_bitrate is None:
        data_bitrate = DEFAULT_DATA_BITRATE
    if data_bitrate is not None:
        if wire.data_bitrate is None:
            wire.data_bitrate = data_bitrate
        elif wire.data_bitrate != data_bitrate:
            raise TimedBusConfigError(
                f"timed channel {channel!r} has a data phase at {wire.data_bitrate} bit/s; "
                f"this bus asked for {data_bitrate}")
