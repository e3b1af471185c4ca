"""The host's figures: data-plane counters summed and per bus, and the buses it is given."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from typing import Any, cast

import can
import canopen

from canbus.master.buslink import BusLink
from canbus.master.channel import DataPlaneStats
from canbus.master.hostconfig import HostConfig
from canbus.master.records import PatchRecord
from canbus.master.sync_producer import SyncProducer
from skin.errors import BusError

Buses = can.BusABC | canopen.Network | Mapping[str, can.BusABC | canopen.Network]


def summed_stats(links: Iterable[BusLink], *, api_dropped: int,
                 callback_errors: int) -> dict[str, int]:
    """Data plane counters summed over the buses, SYNC cycles (the most of any bus),
    overruns, and the API's drops and callback errors."""
    out = {key: 0 for key in DataPlaneStats().snapshot()}  # a host stopped before its start
    cycles = overruns = 0
    for link in links:
        if link.dataplane is not None:
            for key, value in link.dataplane.stats.snapshot().items():
                out[key] = out.get(key, 0) + value
        if link.sync is not None:
            cycles = max(cycles, link.sync.cycle)
            overruns += link.sync.overruns if isinstance(link.sync, SyncProducer) else 0
    out.update(sync_cycles=cycles, sync_overruns=overruns, api_dropped=api_dropped,
               callback_errors=callback_errors)
    return out


def per_bus_stats(links: Mapping[str, BusLink],
                  patches: Iterable[PatchRecord]) -> dict[str, dict[str, Any]]:
    """Per bus: data plane counters, SYNC, patches and force nodes, what receiving
    survived, and the bus's own wire statistics when it keeps them (the timed bus)."""
    records = list(patches)
    out: dict[str, dict[str, Any]] = {}
    for name, link in links.items():
        entry: dict[str, Any] = dict(link.dataplane.stats.snapshot()
                                     if link.dataplane is not None else {})
        sync = link.sync
        entry["sync_cycles"] = sync.cycle if sync is not None else 0
        entry["sync_overruns"] = sync.overruns if isinstance(sync, SyncProducer) else 0
        entry["patches"] = sorted(p.node_id for p in records if p.link is link)
        entry["force_nodes"] = sorted(p.config.force_node for p in records
                                      if p.force_link is link)
        entry["receive"] = link.receive_report()
        wire = getattr(link.bus, "wire_stats", None)
        if callable(wire):
            entry["wire"] = plain(wire())
        out[name] = entry
    return out


def buses_by_name(bus: Buses, config: HostConfig) -> dict[str, can.BusABC | canopen.Network]:
    """The buses a host is given, by the config's bus names (BusError if they differ)."""
    names = [b.name for b in config.buses]
    if isinstance(bus, can.BusABC | canopen.Network):
        if len(names) != 1:
            raise BusError(f"the config has {len(names)} buses ({', '.join(names)}): give the "
                           "host a mapping from each name to its bus")
        return {names[0]: bus}
    given = dict(cast(Mapping[str, can.BusABC | canopen.Network], bus))
    if sorted(given) != sorted(names):
        raise BusError(f"the config's buses are {', '.join(names)}; given "
                       f"{', '.join(given) or 'none'}")
    return given


def plain(value: Any) -> Any:
    """A dataclass (a bus's statistics) as plain JSON-able values."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {k: plain(v) for k, v in dataclasses.asdict(value).items()}
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    return value
