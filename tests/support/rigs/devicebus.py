"""A device and a master on one python-can ``virtual`` channel, each a canopen
:class:`~canopen.Network` of its own, and a spy bus that takes every frame on the channel:
the set-up of a test that serves a node (a patch, a force node) on the device side and
talks to it as a master would, with the one way to wait for its frames.

A test file subclasses :class:`DeviceBus` to add its node, and stops the node in
``close()`` before ``super().close()``::

    class Bench(DeviceBus):
        def __init__(self, channel: str) -> None:
            super().__init__(channel)
            self.server = PatchServer(self.device, Rest(1))
            self.server.start()

        def close(self) -> None:
            self.server.stop()
            super().close()

    @pytest.fixture
    def bench(request: pytest.FixtureRequest) -> Iterator[Bench]:
        with Bench(request.node.name) as bench:
            yield bench

Every frame the spy takes, by whichever method, is kept in :attr:`DeviceBus.seen`, in the
order it came.
"""

from __future__ import annotations

import queue
import time
from collections import Counter
from collections.abc import Callable
from types import TracebackType
from typing import Self

import can
import canopen

from tests.support.rigs.waiting import DEADLINE_S

CYCLE_S = 0.05
"""The notifiers' receive time-out: ``close()`` and ``disconnect()`` join within one cycle."""


def network(channel: str) -> canopen.Network:
    """A canopen network connected to the virtual ``channel``, quick to disconnect."""
    net = canopen.Network()
    net.NOTIFIER_CYCLE = CYCLE_S
    return net.connect(interface="virtual", channel=channel)


class DeviceBus:
    """The device's network, the master's network and the spy, on ``channel``.

    :attr:`spy` sends raw frames too (a malformed request, a SYNC on another COB-ID); the
    spy does not hear its own.
    """

    def __init__(self, channel: str) -> None:
        self.device = network(channel)
        self.master = network(channel)
        self.spy = can.Bus(interface="virtual", channel=channel)
        self.seen: list[can.Message] = []
        self._arrived: queue.Queue[can.Message] = queue.Queue()
        self._notifier = can.Notifier(self.spy, [self._arrived.put], timeout=CYCLE_S)

    def collect(self, seconds: float) -> list[can.Message]:
        """Every frame of the next ``seconds``: a span to watch for what must not come."""
        end = time.monotonic() + seconds
        got: list[can.Message] = []
        while (left := end - time.monotonic()) > 0 and \
                (frame := self._take(left)) is not None:
            got.append(frame)
        return got

    def collect_until(self, enough: Callable[[list[can.Message]], bool], *, what: str
                      ) -> list[can.Message]:
        """Frames from the next one not yet taken until ``enough(frames)``, and not one
        more; AssertionError naming ``what`` after a deadline only a failing run reaches."""
        end = time.monotonic() + DEADLINE_S
        got: list[can.Message] = []
        while not enough(got):
            if (frame := self._take(end - time.monotonic())) is None:
                ids = Counter(f"0x{m.arbitration_id:03X}" for m in got)
                raise AssertionError(f"{what}: not within {DEADLINE_S} s; got {len(got)} "
                                     f"frames, by COB-ID {dict(ids)}")
            got.append(frame)
        return got

    def wait_for(self, matches: Callable[[can.Message], bool], *, what: str) -> can.Message:
        """The first frame, already seen or to come, that ``matches``."""
        for frame in self.seen:
            if matches(frame):
                return frame
        return self.collect_until(lambda got: bool(got) and matches(got[-1]), what=what)[-1]

    def drain(self) -> list[can.Message]:
        """The frames that came and were not yet taken, taken now (what came before a
        request is not its answer)."""
        got: list[can.Message] = []
        while (frame := self._take(0.0)) is not None:
            got.append(frame)
        return got

    def _take(self, timeout: float) -> can.Message | None:
        """The next frame within ``timeout`` s, or None (test ``is None``: a frame without
        data is false, its length is its data's)."""
        try:
            frame = self._arrived.get(timeout=max(0.0, timeout))
        except queue.Empty:
            return None
        self.seen.append(frame)
        return frame

    def close(self) -> None:
        """Stop the spy, then disconnect the master and the device."""
        self._notifier.stop(timeout=1.0)
        self.spy.shutdown()
        self.master.disconnect()
        self.device.disconnect()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        self.close()
