"""Publishing on Zenoh is one way: what arrives on Zenoh never reaches the CAN bus or the
host, and a reader that is slow, killed or restarted changes nothing on the CAN side."""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

pytest.importorskip("zenoh", reason="eclipse-zenoh (the zenoh extra) is not installed")


from canbus.zenoh import schema
from canbus.zenoh.reader import open_session
from tests.support.rigs.children import Child, spawn
from tests.support.rigs.waiting import wait_until
from tests.support.rigs.zenoh_host import Rig, publishing_host

ROOT = Path(__file__).resolve().parents[2]
SYNC = 0x080
CYCLES = 20  # at least, while Zenoh is flooded


class CanSide:
    """Every frame on the host's bus from ``start()`` on, from a bus of its own."""

    def __init__(self, rig: Rig) -> None:
        self.rig = rig
        self.frames: list[can.Message] = []
        self.lock = threading.Lock()
        self.recording = False
        self.first_cycle = self.last_cycle = 0
        self.bus = can.Bus(interface="virtual", channel=rig.channel)
        self.notifier = can.Notifier(self.bus, [self._on], timeout=0.05)

    def _on(self, msg: can.Message) -> None:
        if self.recording:
            with self.lock:
                self.frames.append(msg)

    def start(self) -> None:
        self.first_cycle = self.rig.host.sync.cycle + 1
        self.recording = True

    def stop(self) -> None:
        self.last_cycle = self.rig.host.sync.cycle - 1  # the last cycle whole on both sides
        try:
            wait_until(self._caught_up,
                       what="the CAN side saw every sample the host published")
        finally:
            self.recording = False
            self.notifier.stop()
            self.bus.shutdown()

    def _caught_up(self) -> bool:
        host, frames = self.rig.host, self.rig.by_cycle()
        cycles = range(self.first_cycle, self.last_cycle + 1)
        with self.lock:
            on_bus = [m.arbitration_id for m in self.frames]
        for patch in host.patches:
            tpdos = host.patches[patch].force_node.cob_ids()
            last_tpdo = max(c for c in tpdos if 0x180 <= c < 0x580)
            published = sum(f.published for c in cycles
                            if (f := frames.get((patch, c))) is not None)
            if on_bus.count(last_tpdo) < published:
                return False
        return True

    def check(self) -> None:
        """The host sent SYNCs and its force nodes' frames only; every patch had one sample
        per SYNC, and every sample the host published went onto the bus."""
        host = self.rig.host
        force_ids = {p.force_node.node_id: p.force_node.cob_ids() for p in host.patches.values()}
        own = set().union(*force_ids.values()) | {SYNC}
        patch_ids = {id_ for p in host.patches for id_ in range(0x080 + p, 0x800, 0x080)}
        sent = {m.arbitration_id for m in self.frames} - patch_ids
        assert sent <= own, f"the host sent {sorted(map(hex, sent - own))}"
        syncs = sum(m.arbitration_id == SYNC for m in self.frames)
        frames = self.rig.by_cycle()
        cycles = range(self.first_cycle, self.last_cycle + 1)
        assert len(cycles) >= CYCLES and syncs >= len(cycles)
        for patch in host.patches:
            mine = [frames.get((patch, c)) for c in cycles]
            assert all(f is not None for f in mine), f"patch {patch}: a cycle without a sample"
            published = sum(f.published for f in mine if f is not None)
            # decoding works; how many are complete depends on the machine's load, not Zenoh
            assert sum(f.complete for f in mine if f is not None) >= len(cycles) / 2
            last_tpdo = max(c for c in force_ids[host.patches[patch].force_node.node_id]
                            if 0x180 <= c < 0x580)
            on_bus = sum(m.arbitration_id == last_tpdo for m in self.frames)
            assert on_bus >= published
        stats = host.stats()
        assert stats["callback_errors"] == 0 and stats["send_errors"] == 0
        assert self.rig.publisher.queue.dropped == 0


@contextlib.contextmanager
def can_side(rig: Rig) -> Iterator[CanSide]:
    side = CanSide(rig)
    side.start()
    try:
        yield side
    finally:
        side.stop()


def test_nothing_put_or_asked_on_zenoh_reaches_the_host_or_the_bus() -> None:
    with publishing_host((1, 2)) as rig:
        session = open_session(rig.reader_settings)
        mine = str(session.info.zid())
        try:
            wait_until(lambda: list(session.info.peers_zid()), what="the reader's session "
                       "connected to the host")
            wait_until(rig.by_cycle, what="a first sample of the host")
            with can_side(rig) as side:
                replies = []
                forged = schema.encode_forces(rig.by_cycle()[next(iter(rig.by_cycle()))],
                                              b"test-host", b"default", 0.0, 0.0)
                for k in range(300):
                    for key in ("canskin/test-host/default/forces/1",
                                "canskin/test-host/default/state/1", "canskin/test-host/tare",
                                "canskin/test-host/default/sdo/1", "canskin/test-host/nmt",
                                f"anything/{k}"):
                        session.put(key, forged if k % 2 else bytes([k % 256]) * 8)
                    if k % 50 == 0:
                        replies += list(session.get("**", timeout=0.2))
                        replies += list(session.get("canskin/**", timeout=0.2))
                        replies += list(session.get("@/**", timeout=0.2))
                time.sleep(0.5)  # pacing: for the forged samples to reach whoever listens
                wait_until(lambda: rig.host.sync.cycle - side.first_cycle >= CYCLES + 1,
                           what=f"{CYCLES} whole cycles on the CAN side")
        finally:
            session.close()
    side.check()
    # the host answers nothing: no queryable, no admin space (the asking session's own
    # admin space answers its "@/**" about itself)
    assert replies and {str(r.replier_id.zid) for r in replies if r.replier_id} <= {mine}
    assert rig.publisher.put_errors == 0


def _reader(endpoint: str, delay: float) -> Child:
    reader = spawn([sys.executable, "-m", "tests.support.rigs.zenoh_slow_reader", endpoint,
                    str(delay)], cwd=ROOT)
    reader.wait_for("subscribed", timeout=60)
    return reader


def _got(reader: Child) -> int:
    reader.wait()
    counts = [int(line.split()[1]) for line in reader.stdout().splitlines()
              if line.startswith("got")]
    return max(counts, default=0)


def test_a_slow_killed_and_restarted_reader_changes_nothing_on_the_can_side() -> None:
    with publishing_host((1, 2), period_ms=10.0) as rig, can_side(rig) as side:
        slow = _reader(rig.endpoint, 0.2)  # takes 0.2 s per sample: Zenoh backs up
        slow.wait_for("got 1", timeout=60)
        sent = rig.publisher.sent
        wait_until(lambda: rig.publisher.sent >= sent + 200,  # the host does not wait for it
                   what="200 samples published while the reader is stuck")
        slow.send_signal(signal.SIGKILL)
        fast = _reader(rig.endpoint, 0.0)
        fast.wait_for("got 100", timeout=60)
        fast.send_signal(signal.SIGKILL)
        again = _reader(rig.endpoint, 0.0)
        again.wait_for("got 50", timeout=60)
        assert again.stop(signal.SIGTERM) in (0, -signal.SIGTERM), again.output()
    side.check()
    slow_got = _got(slow)
    assert 1 <= slow_got < 100  # it read a few of the 200 the host published meanwhile
    assert _got(fast) >= 100 and _got(again) >= 50
