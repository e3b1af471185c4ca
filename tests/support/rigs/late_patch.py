"""A patch that answers late on purpose, for the test that late answers never make a mixed
sample (tests/canbus/test_answers_multiprocess.py)::

    python -m tests.support.rigs.late_patch CHANNEL PORT [--split-every 7] [--hold-every 11]

The ``indenter`` scene's patch 1 on udp_multicast, one simulator step per SYNC (so no two
answers are alike), answering like ``skin sim run`` except that every ``--split-every``-th
answer is sent in two parts, its first three TPDOs at once and the other four when the next
SYNC has come (before that SYNC's own answer); and every ``--hold-every``-th answer is held
back whole until the next SYNC has come. That is what a busy device does now and then, here
by count, not by chance: on any machine, however loaded, the recording shows them.

It prints ``Ctrl-C stops`` once it serves, ``answers N`` every 100 answers, and at the end
``split S held H answers A`` (Ctrl-C or SIGTERM ends it).
"""

from __future__ import annotations

import argparse
import signal
import threading
from typing import Any

import can
import canopen

from canbus.device.patch_server import PatchServer
from canbus.device.server_bus import ServerBus
from canbus.device.source import SimulatorSource
from sim import Simulator, load_scene

ANSWER_TPDOS = 7  # a 3-axis answer; anything shorter (an event TPDO) goes out as it is


class LatePatchServer(PatchServer):
    """A :class:`PatchServer` whose answers are split or held back, by count."""

    def __init__(self, *args: Any, split_every: int, hold_every: int, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.split_every, self.hold_every = split_every, hold_every
        self.answers = self.split = self.held = 0
        self._late: list[can.Message] = []  # goes out when the next SYNC has come

    def _send(self, bus: ServerBus, messages: list[can.Message]) -> None:
        """(In the SYNC handler: the SYNC this answers has come, after the one before.)"""
        if len(messages) < ANSWER_TPDOS:
            super()._send(bus, messages)
            return
        late, self._late = self._late, []
        self.answers += 1
        if self.answers % 100 == 0:
            print(f"answers {self.answers}", flush=True)
        if self.answers % self.split_every == 0:
            self._late = messages[3:]
            messages = messages[:3]
            self.split += 1
        elif self.answers % self.hold_every == 0:
            self._late = messages
            messages = []
            self.held += 1
        super()._send(bus, late + messages)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("channel")
    parser.add_argument("port", type=int)
    parser.add_argument("--split-every", type=int, default=7)
    parser.add_argument("--hold-every", type=int, default=11)
    args = parser.parse_args()
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    network = canopen.Network(can.Bus(interface="udp_multicast", channel=args.channel,
                                      port=args.port))
    network.NOTIFIER_CYCLE = 0.05
    network.connect()
    source = SimulatorSource(Simulator(load_scene("indenter")), ahead=10)
    server = LatePatchServer(network, source, accept_only_consumed=True,
                             split_every=args.split_every, hold_every=args.hold_every)
    try:
        with server:
            print("Ctrl-C stops", flush=True)
            threading.Event().wait()
    except KeyboardInterrupt:
        pass
    finally:
        network.disconnect()
    print(f"split {server.split} held {server.held} answers {server.answers}", flush=True)


if __name__ == "__main__":
    main()
