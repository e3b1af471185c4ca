"""The robot-wide contact list of a sample: every patch's summary in its link's frame, the
patches of one link touching one object merged (:func:`skin.placement.merge`).

```python
for cycle, contacts in robot_contacts(host.frames()):
    for c in contacts:          # skin.placement.LinkContact
        c.link, c.point_m, c.force_N, c.normal, c.taxels, c.pressure_Pa
```
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence

from canbus.master.channel import ForceFrame
from skin.placement import LinkContact, PatchOnLink, merge


def contacts_of(frames: Sequence[ForceFrame]) -> list[LinkContact]:
    """The contacts of one sample (the frames of one SYNC cycle): patches without a
    placement or a summary take no part."""
    placed: list[PatchOnLink] = []
    pitch = 0.0
    for frame in frames:
        one = frame.on_link
        if one is not None:
            placed.append(one)
            pitch = max(pitch, frame.pitch_m)
    return merge(placed, pitch) if placed else []


def robot_contacts(frames: Iterable[ForceFrame]) -> Iterator[tuple[int, list[LinkContact]]]:
    """``(cycle, contacts)`` for each SYNC cycle of a stream of frames in publishing order
    (``HostManager.frames()``, a subscriber's batches): a cycle's list is given when the
    next cycle's first frame comes, and the last one when the stream ends."""
    cycle, pending = None, []
    for frame in frames:
        if cycle is not None and frame.cycle != cycle:
            yield cycle, contacts_of(pending)
            pending = []
        cycle = frame.cycle
        pending.append(frame)
    if cycle is not None:
        yield cycle, contacts_of(pending)
