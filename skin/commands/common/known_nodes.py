"""What a host config tells a bus tool about the nodes on the bus it describes.

``skin sniff --config``, ``skin view --config`` and the readers attribute a PDO to a node
only where they know who sends it (:mod:`canbus.tools.attribution`); a host config is that
knowledge: its patches send the mapping of their mode at their predefined COB-IDs (what
the host writes to them), its force nodes send at their ``force_cob_ids`` or predefined
COB-IDs, and its ``other_nodes`` use their predefined TPDO 1..4 (the config check holds
them to it).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from canbus.master.hostconfig import HostConfig, PatchConfig
    from canbus.tools.attribution import KnownNode


def _fd(config: HostConfig, bus: str) -> bool:
    try:
        return bool(config.bus(bus).fd)
    except KeyError:
        return bool(config.buses[0].fd)


def patch_node(config: HostConfig, patch: PatchConfig) -> KnownNode:
    """The patch with the mapping the host gives its mode (CAN FD: its whole answer)."""
    from canbus.master.patch_setup import tpdo_layouts
    from canbus.tools.attribution import KnownNode

    return KnownNode(patch.node_id, "skin-patch",
                     layouts=tpdo_layouts(patch.node_id, patch.mode,
                                          fd=_fd(config, patch.bus)))


def force_node(patch: PatchConfig) -> KnownNode:
    """The patch's force node at its configured COB-IDs, its predefined ones for the rest
    (7 given: TPDO 8, the contact, keeps its own)."""
    from canbus.master.cobids import force_tpdo_cob_ids
    from canbus.tools.attribution import KnownNode

    given = patch.force_cob_ids or ()
    cob_ids = (*given, *force_tpdo_cob_ids(patch.force_node)[len(given):])
    return KnownNode(patch.force_node, "skin-forces", cob_ids=tuple(cob_ids))


def known_nodes(config: HostConfig, *, bus: str | None = None) -> list[KnownNode]:
    """Every node ``config`` places on ``bus`` (default: all its buses)."""
    from canbus.tools.attribution import KnownNode

    out: list[KnownNode] = []
    for patch in config.patches:
        if bus is None or (patch.bus or config.buses[0].name) == bus:
            out.append(patch_node(config, patch))
        if bus is None or (patch.force_bus or patch.bus or config.buses[0].name) == bus:
            out.append(force_node(patch))
    out += [KnownNode(node, None) for node in config.other_nodes]
    return out
