"""canbus.busio: a notifier that survives its bus and its listeners, a bus that is opened
again, and one that is gone for good."""

from __future__ import annotations

import itertools
import threading
import time

import can
import pytest

from canbus.busio import BusGoneError, ResilientBus
from canbus.receiveloop import PAUSE_MAX_S, ReceiveLoop
from tests.support.rigs.host import eventually

FRAME = can.Message(arbitration_id=0x181, data=b"\x01\x02", is_extended_id=False)


class Scripted(can.BusABC):
    """A bus whose recv raises ``fails`` times, then hands out ``FRAME`` once, then waits."""

    def __init__(self, fails: int = 0, *, always: bool = False) -> None:
        self.fails, self.always = fails, always
        self.calls = 0
        self.tries: list[float] = []  # time.monotonic() of each recv
        self.sent: list[can.Message] = []
        self.channel_info = "scripted"
        self._given = False
        super().__init__(channel="scripted")

    def recv(self, timeout: float | None = None) -> can.Message | None:
        self.calls += 1
        self.tries.append(time.monotonic())
        if self.always or self.fails > 0:
            self.fails -= 1
            raise can.CanOperationError("could not unpack received message")
        if not self._given:
            self._given = True
            return FRAME
        time.sleep(min(timeout or 0.01, 0.01))  # pacing: an idle bus waits out its timeout
        return None

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self.recv(timeout), True

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self.always:
            raise can.CanOperationError("Network is down")
        self.sent.append(msg)


@pytest.fixture
def received() -> list[can.Message]:
    return []


def test_a_burst_of_failures_drains_at_once_and_the_frame_after_it_arrives(
        received: list[can.Message]) -> None:
    bus = Scripted(fails=500)  # 500 garbage datagrams queued before a good frame
    loop = ReceiveLoop(bus, [received.append], timeout=0.01)
    try:
        eventually(lambda: received, "the frame after the burst", timeout=10.0)
        assert loop.report()["errors"] == 500 and loop.exception is None
        assert loop.report()["failing_since"] is None  # the spell ended
    finally:
        loop.stop()


def test_a_listener_that_raises_is_counted_and_the_others_still_get_the_frame(
        received: list[can.Message]) -> None:
    def broken(msg: can.Message) -> None:
        raise ValueError("a bug in a listener")

    bus = Scripted()
    loop = ReceiveLoop(bus, [broken, received.append], timeout=0.01)
    try:
        eventually(lambda: received, "the frame")
        assert loop.report()["listener_errors"] == 1
        assert "a bug in a listener" in loop.report()["last_error"]
        assert any(t.name == 'Notifier for bus "scripted"' for t in threading.enumerate())
    finally:
        loop.stop()


def _slowest_of_last(tries: list[float], count: int) -> float:
    """The shortest of the last ``count`` gaps between tries (0 before there are that many)."""
    last = list(tries)[-count - 1:]
    if len(last) <= count:
        return 0.0
    return min(later - earlier for earlier, later in itertools.pairwise(last))


def test_a_bus_that_keeps_failing_at_once_does_not_spin_a_core() -> None:
    """Once a spell of failures is past its young part (a burst draining), every try waits
    a pause that doubles up to PAUSE_MAX_S: a bus failing for good is tried about twice a
    second. A pause never ends early, so a loop that pauses shows four tries in a row that
    far apart however loaded the machine is; one that spins (~100,000 tries a second) never
    does."""
    bus = Scripted(always=True)
    loop = ReceiveLoop(bus, [], timeout=0.01)
    try:
        eventually(lambda: _slowest_of_last(bus.tries, 4) >= 0.9 * PAUSE_MAX_S,
                   "four tries in a row of a failing bus, each a full pause after the last")
        assert loop.exception is None and loop.report()["errors"] >= len(bus.tries) - 1
    finally:
        loop.stop()


def test_a_resilient_bus_survives_one_failure_without_opening_again() -> None:
    opened: list[Scripted] = []

    def opener() -> can.BusABC:
        opened.append(Scripted(fails=1))
        return opened[-1]

    bus = ResilientBus(opener, name="one")
    try:
        assert bus.recv(0.01) is None  # the failure, survived
        assert bus.recv(0.01) is FRAME
        assert bus.stats.errors == 1 and bus.stats.reopens == 0 and len(opened) == 1
        bus.send(FRAME)
        assert opened[0].sent == [FRAME]
    finally:
        bus.shutdown()


def test_a_resilient_bus_that_cannot_be_opened_again_is_gone() -> None:
    opened: list[Scripted] = []

    def opener() -> can.BusABC:
        if opened:
            raise can.CanInitializationError("no such interface")
        opened.append(Scripted(always=True))
        return opened[-1]

    def until_gone(bus: ResilientBus) -> None:
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            bus.recv(0.05)

    bus = ResilientBus(opener, name="x", give_up_s=0.5)
    try:
        with pytest.raises(BusGoneError, match=r"bus x: gone \(cannot open it again"):
            until_gone(bus)
        assert bus.gone.is_set() and bus.stats.failed_opens >= 1
        with pytest.raises(BusGoneError):
            bus.recv(0.0)
        with pytest.raises(can.CanOperationError):
            bus.send(FRAME)
    finally:
        bus.shutdown()


def test_a_resilient_bus_keeps_its_periodic_frames_going_through_failed_sends() -> None:
    inner = Scripted(always=True)  # every send fails for now
    bus = ResilientBus(lambda: inner, name="p", bus=inner)
    task = bus.send_periodic(FRAME, 0.01)
    try:
        eventually(lambda: bus.stats.periodic_send_errors >= 3, "failed periodic sends")
        inner.always = False  # the bus works again: the task is still there
        eventually(lambda: len(inner.sent) >= 3, "periodic frames sent again")
    finally:
        task.stop()
        bus.shutdown()
