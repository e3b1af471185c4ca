"""How many buses a skin needs: the smallest number that keeps every bus under the target
load, classic CAN or CAN FD, counted as :func:`canbus.busload.plan` counts every frame.

For ``forces="same-bus"`` (each patch's force node on the patch's bus) and ``"none"`` the
patches are spread over 1, 2, ... buses in node order until every bus's worst-case load
is at most the target. For ``"other-bus"`` the patch buses are sized with their patches'
frames alone and the force nodes get buses of their own, sized the same way (force PDOs
follow the decode, no SYNC there). Beside the count: the worst bus's load at that size and
the highest sample rate every one of those buses carries under the target.

A bus's load grows with its patches, so the fewest buses are ``ceil(N / m)`` for ``m`` the
most patches one bus carries under the target, found by bisection on one node's share
(``canbus.nodeload``): constant time per bus size, whatever N. ``exact=True`` tries 1, 2, ...
buses with every frame listed (``canbus.busload.plan(exact=True)``), as the first planner
did: the oracle the arithmetic is tested against.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from canbus.busload import Forces, Plan, plan
from canbus.nodeload import BusFigures, Traffic, bus_figures, most_under


@dataclass(frozen=True)
class Sizing:
    """The buses ``patches`` patches need at ``rate_hz`` under ``target_pct``."""

    fd: bool
    bitrate: int
    data_bitrate: int | None
    buses: int | None
    """Patch buses needed; None: one patch alone on a bus is above the target."""
    force_buses: int | None
    """Buses of force PDOs alone (``forces="other-bus"``); 0 otherwise; None: one force
    node alone is above the target."""
    patches_per_bus: tuple[int, int]
    """The fewest and the most patches on one bus at that size."""
    load_worst_pct: float
    """The most loaded bus's worst-case load at that size (patch and force buses)."""
    max_rate_hz: float
    """The highest sample rate every bus of that size carries under the target (at one
    patch per bus when even that is above the target)."""


def _smallest(patches: int, make: Callable[[int], Plan],
              fits: Callable[[Plan], bool]) -> tuple[int | None, Plan]:
    """The fewest buses (1..patches) whose plan ``fits``; None and the last plan tried."""
    last = make(1)
    for buses in range(1, patches + 1):
        last = make(buses)
        if fits(last):
            return buses, last
    return None, last


def size(patches: int, rate_hz: float, mode: str, bitrate: int, *,
         data_bitrate: int | None = None, target_pct: float = 70.0,
         forces: Forces = "same-bus", heartbeat_ms: int = 100,
         force_heartbeat_ms: int = 1000, contact: bool = True, exact: bool = False) -> Sizing:
    """The buses needed (module docstring); ``data_bitrate`` set means CAN FD; ``contact``
    False: force nodes without the contact PDO (as :func:`canbus.busload.plan`)."""
    if exact:
        return _size_exactly(patches, rate_hz, mode, bitrate, data_bitrate=data_bitrate,
                             target_pct=target_pct, forces=forces, heartbeat_ms=heartbeat_ms,
                             force_heartbeat_ms=force_heartbeat_ms, contact=contact)
    t = Traffic.of(rate_hz, mode, bitrate, data_bitrate, heartbeat_ms=heartbeat_ms,
                   force_heartbeat_ms=force_heartbeat_ms, contact=contact)
    with_forces = forces == "same-bus"

    def patch_bus(n: int) -> BusFigures:
        return bus_figures(t, n, n if with_forces else 0, True, target_pct)

    def force_bus(n: int) -> BusFigures:
        return bus_figures(t, 0, n, False, target_pct)

    buses, most = fewest_buses(patches, patch_bus, target_pct)
    shown = [patch_bus(most)]
    force_buses: int | None = 0
    if forces == "other-bus":
        force_buses, most_forces = fewest_buses(patches, force_bus, target_pct)
        shown.append(force_bus(most_forces))
    fewest = patches // buses if buses is not None else 1
    return Sizing(fd=data_bitrate is not None, bitrate=bitrate, data_bitrate=data_bitrate,
                  buses=buses, force_buses=force_buses, patches_per_bus=(fewest, most),
                  load_worst_pct=max(b.load_worst_pct for b in shown),
                  max_rate_hz=min(b.max_rate_hz for b in shown))


def fewest_buses(nodes: int, bus: Callable[[int], BusFigures],
                 target_pct: float) -> tuple[int | None, int]:
    """The fewest buses that carry ``nodes`` nodes in node order each under the target, and
    the most nodes on one of them; (None, 1) when one node alone is above the target."""
    most = most_under(lambda n: bus(n).load_worst_pct, target_pct, nodes)
    if most == 0:
        return None, 1
    buses = math.ceil(nodes / most)
    return buses, math.ceil(nodes / buses)


def _size_exactly(patches: int, rate_hz: float, mode: str, bitrate: int, *,
                  data_bitrate: int | None, target_pct: float, forces: Forces,
                  heartbeat_ms: int, force_heartbeat_ms: int, contact: bool) -> Sizing:
    """:func:`size` with every frame of every bus counted, 1, 2, ... buses in turn."""

    def patch_buses(buses: int) -> Plan:
        return plan(patches, rate_hz, mode, bitrate, data_bitrate=data_bitrate,
                    target_pct=target_pct, buses=buses,
                    forces="none" if forces == "other-bus" else forces,
                    heartbeat_ms=heartbeat_ms, force_heartbeat_ms=force_heartbeat_ms,
                    contact=contact, exact=True)

    buses, chosen = _smallest(patches, patch_buses, lambda p: not p.over_target)
    loads = [b.load_worst_pct for b in chosen.buses]
    rates = [chosen.max_rate_hz]
    force_buses: int | None = 0
    if forces == "other-bus":
        def force_plan(count: int) -> Plan:  # one force bus of ceil(patches / count) nodes
            group = math.ceil(patches / count)
            return plan(group, rate_hz, mode, bitrate, data_bitrate=data_bitrate,
                        target_pct=target_pct, forces="other-bus",
                        heartbeat_ms=heartbeat_ms, force_heartbeat_ms=force_heartbeat_ms,
                        contact=contact, exact=True)

        force_buses, forced = _smallest(patches, force_plan,
                                        lambda p: not p.buses[-1].over_target)
        force_bus = forced.buses[-1]
        loads.append(force_bus.load_worst_pct)
        rates.append(force_bus.max_rate_hz)
    sizes = [len(b.patches) for b in chosen.buses if b.patches]
    return Sizing(fd=data_bitrate is not None, bitrate=bitrate, data_bitrate=data_bitrate,
                  buses=buses, force_buses=force_buses,
                  patches_per_bus=(min(sizes), max(sizes)), load_worst_pct=max(loads),
                  max_rate_hz=min(rates))
