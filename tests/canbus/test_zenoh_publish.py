"""A host's forces and events on Zenoh, read back through ``subscribe``: the same frames
as the host's own API, by patch, bus, host or the whole skin; the ring buffer; events."""

from __future__ import annotations

import can
import numpy as np
import pytest

pytest.importorskip("zenoh", reason="eclipse-zenoh (the zenoh extra) is not installed")

from canbus.master.dataplane import ForceFrame
from canbus.zenoh.reader import open_session, subscribe, subscribe_events
from tests.support.rigs.waiting import wait_until
from tests.support.rigs.zenoh_host import publishing_host


def _same(a: ForceFrame, b: ForceFrame) -> None:
    assert (a.patch, a.force_node, a.cycle, a.sync_counter) == \
        (b.patch, b.force_node, b.cycle, b.sync_counter)
    assert a.timestamp == b.timestamp
    assert np.array_equal(a.force_N, b.force_N)  # bit for bit: float64 on the wire
    assert a.force_N.dtype == b.force_N.dtype == np.float64
    assert np.array_equal(a.valid, b.valid) and a.valid.dtype == b.valid.dtype
    assert np.array_equal(a.reason, b.reason) and a.reason.dtype == b.reason.dtype
    assert (a.complete, a.published) == (b.complete, b.published)


def test_subscribers_get_the_frames_the_api_gives_by_patch_bus_host_and_skin() -> None:
    with publishing_host((1, 2)) as rig:
        settings = rig.reader_settings
        with subscribe(settings=settings) as skin, \
                subscribe(patch=2, settings=settings) as one, \
                subscribe(host="test-host", bus="default", settings=settings) as bus, \
                subscribe(host="another-host", settings=settings) as nobody:
            wait_until(lambda: skin.received >= 40 and one.received >= 20 and bus.received,
                       what="40 samples of the skin, 20 of patch 2")
        # closed, each subscription's iterator gives what it holds and ends
        got = list(skin.samples(timeout=0.2))
        got_one = list(one.frames(timeout=0.2))
        got_bus = list(bus.frames(timeout=0.2))
        assert nobody.received == 0
    api = rig.by_cycle()
    assert len(got) >= 40
    for sample in got:
        assert (sample.host, sample.bus) == ("test-host", "default")
        assert sample.frame.timestamp <= sample.published <= sample.sent <= sample.received
        _same(sample.frame, api[(sample.frame.patch, sample.frame.cycle)])
    assert {f.patch for f in got_one} == {2}
    assert {f.patch for f in got_bus} == {1, 2}
    assert any(s.frame.complete and s.frame.force_N[:, 2].max() > 0.5 for s in got)
    # nothing lost or reordered on loopback: each patch's cycles come in order, gap-free
    for patch in (1, 2):
        cycles = [s.frame.cycle for s in got if s.frame.patch == patch]
        assert cycles == list(range(cycles[0], cycles[0] + len(cycles)))


def test_a_ring_buffer_keeps_the_newest_and_counts_the_rest() -> None:
    with publishing_host((1,)) as rig, subscribe(settings=rig.reader_settings, ring=3) as sub:
        wait_until(lambda: sub.received >= 10, what="10 samples")
        held = sub.newest()
        latest = sub.latest()
    assert len(held) == 3
    assert [s.frame.cycle for s in held] == sorted(s.frame.cycle for s in held)
    assert sub.dropped == sub.received - len(sub.newest()) >= 7
    assert latest[("test-host", 1)].frame.cycle >= held[-1].frame.cycle


def test_state_changes_emcys_and_statistics_arrive_as_events() -> None:
    events: list[tuple[str, dict[str, object]]] = []
    with publishing_host((1,)) as rig:
        session = open_session(rig.reader_settings)
        try:
            subscribe_events(lambda key, fields: events.append((key, fields)),
                             session=session)
            wait_until(lambda: any(k.endswith("/stats") for k, _ in events),
                       what="the first statistics event: the subscription is live")
            emcy = can.Message(arbitration_id=0x81, is_extended_id=False,
                               data=[0x00, 0x50, 0x81, 4, 0x01, 0, 0, 0])
            rig.patch_bus.send(emcy)
            wait_until(lambda: any("/emcy/" in k for k, _ in events), what="the EMCY event")
            rig.server.stop()  # the patch falls silent: lost after two heartbeat periods
            wait_until(lambda: any(f.get("state") == "lost" for _, f in events),
                       what="the state event")
            wait_until(lambda: any(k.endswith("/stats") for k, _ in events),
                       what="a statistics event")
        finally:
            session.close()
    emcys = [f for k, f in events if k == "canskin/test-host/default/emcy/1"]
    assert emcys and emcys[0]["code"] == 0x5000 and emcys[0]["data"] == bytes([4, 1, 0, 0, 0])
    states = [f for k, f in events if k == "canskin/test-host/default/state/1"]
    assert states[-1]["state"] == "lost" and states[-1]["previous"] == "operational"
    stats = [f for k, f in events if k == "canskin/test-host/stats"]
    assert stats and stats[0]["host"] == "test-host"
    assert stats[0]["stats"]["samples"] > 0 and stats[0]["zenoh"]["sent"] > 0
    assert stats[0]["patches"][0]["patch"] == 1
