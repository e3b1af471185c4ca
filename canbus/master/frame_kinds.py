"""Which frames on a patch bus are the bus's own CANopen traffic, not unknown.

The data plane takes the patches' PDOs; every other frame it is handed is either the
bus's own traffic (SYNC, NMT, TIME, LSS, every node's heartbeat, EMCY and SDO, the host's
force nodes' PDOs as a recording holds them, the ``other_nodes``' predefined PDOs) or
unknown: a PDO of no channel (a lost or removed patch's, a node nobody configured), a
29-bit or remote frame, an identifier outside the predefined connection set. Only the
latter are ``unknown_frames``: a clean run counts none.
"""

from __future__ import annotations

from canbus.master.cobids import HostNodes, force_cob_ids, node_cob_ids

NMT, SYNC, TIME, LSS = 0x000, 0x080, 0x100, (0x7E4, 0x7E5)
SERVICE_COB_IDS = frozenset((NMT, SYNC, TIME, *LSS,
                             *range(0x081, 0x100),  # EMCY
                             *range(0x581, 0x600), *range(0x601, 0x680),  # SDO
                             *range(0x701, 0x780)))  # NMT error control (heartbeat, boot-up)
"""Every COB-ID of a CANopen service of some node: never unknown."""


def bus_cob_ids(config: HostNodes, bus: str) -> frozenset[int]:
    """The COB-IDs of ``bus``'s own traffic beside the patches' PDOs (module docstring)."""
    ids = set(SERVICE_COB_IDS)
    for patch in config.patches:
        if (patch.force_bus or patch.bus) == bus:
            ids |= force_cob_ids(patch)
    for node in config.other_nodes:
        ids |= set(node_cob_ids(node))
    return frozenset(ids)
