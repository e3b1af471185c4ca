"""The robot-wide contact list on Zenoh: its key, its bytes, and the publisher's grouping
of a bus's frames into cycles (docs/robot.md, docs/zenoh.md).

Key ``{prefix}/{host}/{bus}/contacts``, one message per SYNC cycle of a bus that has a
patch placed on a link, encoding ``application/msgpack;canskin.contacts.v1``: a msgpack
map ``{"v": 1, "host", "bus", "cycle", "time" (the SYNC's, s since the epoch),
"contacts": [...]}``, each contact ``{"link", "point_m" [x, y, z], "force_N" [x, y, z],
"normal" [x, y, z], "patches" [node-ID, ...], "taxels" [[node-ID, taxel], ...],
"pressure_Pa"}`` in the link's frame (SI units, float64: the API's values bit for bit).
An empty list: no contact on that bus's links in that cycle.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from canbus.master.channel import ForceFrame
from canbus.master.robot import contacts_of
from canbus.zenoh.schema import SchemaError, decode_event, encode_event
from skin.placement import LinkContact

CONTACTS_ENCODING = "application/msgpack;canskin.contacts.v1"


def contacts_key(prefix: str, host: str, bus: str) -> str:
    """``{prefix}/{host}/{bus}/contacts``."""
    return f"{prefix}/{host}/{bus}/contacts"


def encode_contacts(host: str, bus: str, cycle: int, time_s: float,
                    contacts: list[LinkContact]) -> bytes:
    return encode_event({"host": host, "bus": bus, "cycle": cycle, "time": time_s,
                         "contacts": [c.to_dict() for c in contacts]})


def decode_contacts(payload: bytes | bytearray | memoryview
                    ) -> tuple[dict[str, Any], list[LinkContact]]:
    """The message's fields and its contacts; :class:`SchemaError` if it is not one."""
    fields = decode_event(payload)
    try:
        contacts = [LinkContact(c["link"], np.array(c["point_m"], dtype=np.float64),
                                np.array(c["force_N"], dtype=np.float64),
                                np.array(c["normal"], dtype=np.float64),
                                tuple((int(n), int(k)) for n, k in c["taxels"]),
                                float(c["pressure_Pa"]))
                    for c in fields["contacts"]]
    except (KeyError, TypeError, ValueError) as err:
        raise SchemaError(f"not a contact list: {err!r}") from err
    return fields, contacts


class CycleGroups:
    """A bus's frames, in publishing order, grouped into cycles: :meth:`add` gives a
    cycle's frames once every patch of the bus has given one (or the next cycle began)."""

    def __init__(self, patches: int) -> None:
        self.patches = patches
        self.cycle: int | None = None
        self.frames: list[ForceFrame] = []

    def add(self, frame: ForceFrame) -> list[list[ForceFrame]]:
        done = []
        if self.cycle is not None and frame.cycle != self.cycle and self.frames:
            done.append(self.frames)
            self.frames = []
        self.cycle = frame.cycle
        self.frames.append(frame)
        if len(self.frames) >= self.patches:
            done.append(self.frames)
            self.frames = []
        return done

    def rest(self) -> list[list[ForceFrame]]:
        done, self.frames = ([self.frames] if self.frames else []), []
        return done


def contacts_message(host: str, bus: str, frames: list[ForceFrame]) -> bytes:
    return encode_contacts(host, bus, frames[0].cycle, frames[0].timestamp, contacts_of(frames))
