"""The robot-wide contact list on Zenoh (``{prefix}/{host}/{bus}/contacts``): one message a
cycle, the contacts the host's API gives for that cycle's frames, bit for bit."""

from __future__ import annotations

import threading

import numpy as np
import pytest

pytest.importorskip("zenoh", reason="eclipse-zenoh (the zenoh extra) is not installed")

import zenoh

from canbus.master.robot import contacts_of
from canbus.zenoh.contacts import CONTACTS_ENCODING, contacts_key, decode_contacts
from canbus.zenoh.reader import open_session
from skin.placement import LinkContact, PatchPlacement, Pose
from tests.support.rigs.waiting import wait_until
from tests.support.rigs.zenoh_host import publishing_host

PALM = {1: PatchPlacement("palm", Pose((-0.0225, 0.0, 0.01))),
        2: PatchPlacement("palm", Pose((0.0225, 0.0, 0.01)))}


def test_each_cycles_contacts_on_the_links_arrive_as_the_api_gives_them() -> None:
    got: list[tuple[dict[str, object], list[LinkContact], str]] = []
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        fields, contacts = decode_contacts(sample.payload.to_bytes())
        with lock:
            got.append((fields, contacts, str(sample.encoding)))

    with publishing_host((1, 2), placements=PALM) as rig:
        session = open_session(rig.reader_settings)
        try:
            key = contacts_key(rig.publisher.settings.prefix, "test-host", "default")
            subscriber = session.declare_subscriber(key, on_sample)
            wait_until(lambda: len(got) >= 20, what="20 cycles' contact lists")
            subscriber.undeclare()
        finally:
            session.close()
        api = rig.by_cycle()
    with lock:
        received = list(got)
    for fields, contacts, encoding in received:
        assert encoding == CONTACTS_ENCODING
        cycle = int(fields["cycle"])  # type: ignore[call-overload]
        expected = contacts_of([api[(1, cycle)], api[(2, cycle)]])
        assert [c.to_dict() for c in contacts] == [c.to_dict() for c in expected]
    # the rig presses every taxel of both palm patches: one contact resting on both
    pressed = [contacts for _, contacts, _ in received if contacts]
    assert pressed and all(len(c) == 1 and c[0].patches == (1, 2) for c in pressed)
    assert all(np.isclose(np.linalg.norm(c[0].normal), 1.0) for c in pressed)
