"""Events on python-can's virtual channels that tests wait for (no sleeping on a guess)."""

from __future__ import annotations

import threading

import can
import can.interfaces.virtual


def listening(channel: str) -> bool:
    """A ``can.Notifier`` (a sniffer's, a host's) receives on ``channel``."""
    return any(t.name.startswith("Notifier for bus") and channel in t.name
               for t in threading.enumerate())


def read_out(channel: str, *mine: can.BusABC) -> bool:
    """Every bus of ``channel`` but ``mine`` has taken every frame sent to it: a receiver
    stopped now loses nothing (a virtual bus queues each frame for every other bus)."""
    queues = can.interfaces.virtual.channels.get(channel, [])
    own = {id(bus.queue) for bus in mine}  # type: ignore[attr-defined]
    return all(q.empty() for q in queues if id(q) not in own)
