"""Which COB-IDs the nodes of a host may transmit on, and a check that no two share one
on the same bus.

The check covers every COB-ID a node on a bus may transmit on: NMT 0x000, SYNC 0x080,
TIME 0x100, and for each patch, force node and ``other_nodes`` entry on that bus its CiA
301 predefined connection set (EMCY, TPDOs, RPDOs of the other nodes, SDO both ways,
heartbeat) plus any COB-IDs the config sets. Node-IDs are unique across the host (a patch
is named by its node-ID in the API), COB-IDs only per bus: two buses are two networks.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

from skin.errors import ConfigError

NMT, SYNC, TIME = 0x000, 0x080, 0x100
_TPDO_BASES = (0x180, 0x280, 0x380, 0x480, 0x200, 0x300, 0x400)
_RPDO_BASES = (0x200, 0x300, 0x400, 0x500)
# CiA 301 table 43: identifiers no PDO may use (NMT, SYNC/EMCY of node 0, TIME, SDO, NMT
# error control and LSS ranges).
_RESTRICTED = ((0x000, 0x07F), (0x080, 0x080), (0x100, 0x180), (0x581, 0x5FF), (0x601, 0x67F),
               (0x6E0, 0x6FF), (0x701, 0x77F), (0x780, 0x7FF))


class PatchNodes(Protocol):
    """What the COB-ID rules read of a patch's config (``hostconfig.PatchConfig``)."""

    @property
    def node_id(self) -> int: ...
    @property
    def force_node(self) -> int: ...
    @property
    def force_cob_ids(self) -> tuple[int, ...] | None: ...
    @property
    def bus(self) -> str: ...
    @property
    def force_bus(self) -> str: ...


class _Named(Protocol):
    @property
    def name(self) -> str: ...


class HostNodes(Protocol):
    """What the COB-ID check reads of a host's config (``hostconfig.HostConfig``)."""

    @property
    def patches(self) -> Sequence[PatchNodes]: ...
    @property
    def other_nodes(self) -> Sequence[int]: ...
    @property
    def buses(self) -> Sequence[_Named]: ...


def predefined_tpdo_cob_ids(node_id: int) -> tuple[int, ...]:
    """TPDO 1..7 of the patch and force EDS: 0x180..0x480 and 0x200..0x400 + node-ID."""
    return tuple(base + node_id for base in _TPDO_BASES)


def force_tpdo_cob_ids(node_id: int) -> tuple[int, ...]:
    """TPDO 1..8 of the force EDS: the patch's 7, and the contact's at 0x500 + node-ID
    (RPDO 4's identifier, free on a node without RPDOs)."""
    return (*predefined_tpdo_cob_ids(node_id), 0x500 + node_id)


def node_cob_ids(node_id: int) -> dict[int, str]:
    """Every COB-ID a CANopen node may transmit on in the predefined connection set."""
    ids = {0x080 + node_id: "EMCY", 0x580 + node_id: "SDO tx", 0x600 + node_id: "SDO rx",
           0x700 + node_id: "heartbeat"}
    for n, base in enumerate(_TPDO_BASES[:4], start=1):
        ids[base + node_id] = f"TPDO {n}"
    for n, base in enumerate(_RPDO_BASES, start=1):
        ids.setdefault(base + node_id, f"RPDO {n}")
    return ids


def force_cob_ids(patch: PatchNodes) -> frozenset[int]:
    """Every COB-ID the force node of ``patch`` transmits on: its TPDOs as configured,
    EMCY, SDO responses and heartbeat."""
    return frozenset({0x080 + patch.force_node, 0x580 + patch.force_node,
                      0x700 + patch.force_node, *_force_tpdos(patch)})


def _force_tpdos(patch: PatchNodes) -> tuple[int, ...]:
    """The force node's TPDO 1..8 COB-IDs as configured (7 given: TPDO 8 its own)."""
    default = force_tpdo_cob_ids(patch.force_node)
    given = patch.force_cob_ids or ()
    return (*given, *default[len(given):])


def restricted(cob_id: int) -> bool:
    """A COB-ID CiA 301 reserves for other services (no PDO may use it)."""
    return any(lo <= cob_id <= hi for lo, hi in _RESTRICTED)


def check_cob_ids(config: HostNodes) -> None:
    """Refuse a config in which two nodes share a node-ID, or two transmitters on one bus
    could share a COB-ID."""
    nodes: dict[int, str] = {}
    for i, node in enumerate(config.other_nodes):
        _claim_node(nodes, node, f"host.other_nodes[{i}]")
    for i, patch in enumerate(config.patches):
        _claim_node(nodes, patch.node_id, f"patches[{i}].node_id")
        _claim_node(nodes, patch.force_node, f"patches[{i}].force_node")
    for bus in config.buses:
        _check_bus(config, bus.name)


def _claim_node(nodes: dict[int, str], node_id: int, where: str) -> None:
    if node_id in nodes:
        raise ConfigError(where, f"node-ID {node_id} is also {nodes[node_id]}")
    nodes[node_id] = where


def _check_bus(config: HostNodes, bus: str) -> None:
    owner: dict[int, str] = {NMT: "NMT", SYNC: "SYNC", TIME: "TIME"}
    on = f" on bus {bus!r}" if len(config.buses) > 1 else ""

    def claim(cob_id: int, what: str, where: str) -> None:
        if cob_id in owner:
            raise ConfigError(where, f"0x{cob_id:03X} ({what}) is also {owner[cob_id]}{on}")
        owner[cob_id] = what

    for i, node in enumerate(config.other_nodes):
        for cob_id, service in node_cob_ids(node).items():
            claim(cob_id, f"host.other_nodes[{i}] {service}", f"host.other_nodes[{i}]")
    for i, patch in enumerate(config.patches):
        if patch.bus != bus:
            continue
        where = f"patches[{i}]"
        own = {**node_cob_ids(patch.node_id), **_tpdos(predefined_tpdo_cob_ids(patch.node_id))}
        for cob_id, service in own.items():
            claim(cob_id, f"{where}.node_id {service}", f"{where}.node_id")
    for i, patch in enumerate(config.patches):
        if patch.force_bus != bus:
            continue
        where = f"patches[{i}]"
        services = node_cob_ids(patch.force_node)
        default_tpdos = force_tpdo_cob_ids(patch.force_node)
        for cob_id in set(services) - set(default_tpdos):
            claim(cob_id, f"{where}.force_node {services[cob_id]}", f"{where}.force_node")
        given = len(patch.force_cob_ids or ())
        tpdos = list(enumerate(_force_tpdos(patch)))
        for k, cob_id in tpdos[given:] + tpdos[:given]:  # a clash is named where it was given
            field = f"{where}.force_cob_ids[{k}]" if k < given else f"{where}.force_node"
            claim(cob_id, f"{where}.force_node TPDO {k + 1}", field)


def _tpdos(cob_ids: tuple[int, ...]) -> dict[int, str]:
    return {cob_id: f"TPDO {n}" for n, cob_id in enumerate(cob_ids, start=1)}
