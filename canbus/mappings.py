"""The CAN FD mappings canskin's devices use: a whole answer, or a whole sample, in TPDO 1.

CiA 1301 lets a PDO hold up to 64 bytes. On a CAN FD bus the host maps a patch's answer
into TPDO 1 (its codes, then 0x2006, the counter of the SYNC it answers) and its force
node's sample into TPDO 1 (27 forces, 0x2005, 0x2006, the contact's net Fz, CoP and state);
TPDO 2..8 are invalid. A master
learns a patch's mapping from the host's SDO writes; a force node is the host's own,
mapped in place, so a tool reading the bus adopts :func:`force_fd_entries` when it sees a
force node's TPDO 1 arrive as a CAN FD frame longer than its classic mapping.
"""

from __future__ import annotations

from canbus.pdo_codec import MappedEntry

RESISTANCES, FORCES, VALID, ANSWERED, CONTACT = 0x2000, 0x2000, 0x2005, 0x2006, 0x2008
CONTACT_FD = ((3, 16), (7, 16), (8, 16), (11, 8))
"""The contact sub-indices a CAN FD force sample carries: net Fz, CoP x, y, state."""


def patch_fd_entries(mode: str) -> tuple[MappedEntry, ...]:
    """A patch's whole answer: its codes (27 taxel-major z, x, y; or the 9 z), then 0x2006."""
    if mode == "xyz":
        subs = list(range(1, 28))
    elif mode == "z":
        subs = [3 * t + 1 for t in range(9)]
    else:
        raise ValueError(f"mode must be 'z' or 'xyz', got {mode!r}")
    return (*(MappedEntry(RESISTANCES, s, 16) for s in subs), MappedEntry(ANSWERED, 0, 8))


def force_fd_entries() -> tuple[MappedEntry, ...]:
    """A force node's whole sample: 27 forces, 0x2005, 0x2006 (57 bytes), then its contact's
    net Fz, CoP x, y and state (64 bytes, the frame a 57-byte sample takes anyway; a node
    without a contact summary says so there: state ``unknown``, no values)."""
    return (*(MappedEntry(FORCES, k, 16) for k in range(1, 28)), MappedEntry(VALID, 0, 16),
            MappedEntry(ANSWERED, 0, 8),
            *(MappedEntry(CONTACT, sub, bits) for sub, bits in CONTACT_FD))
