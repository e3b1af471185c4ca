"""The timed wire's measured load falls inside ``skin plan``'s range for the same traffic."""

from __future__ import annotations

import random
from collections.abc import Callable

import can
import pytest

from canbus.busload import PlannedFrame, plan
from canbus.timed import TimedBus

OpenBus = Callable[..., TimedBus]


def _payload(f: PlannedFrame, cycle: int, rng: random.Random) -> bytes:
    if f.kind == "sync":
        return bytes([cycle % 240 + 1])
    if f.kind == "heartbeat":
        return b"\x05"  # operational
    return rng.randbytes(f.data_bytes)  # resistance codes and forces: any bits


@pytest.mark.parametrize(("mode", "fd", "forces"), [
    ("xyz", False, "same-bus"), ("z", False, "same-bus"), ("xyz", True, "same-bus"),
    ("xyz", False, "none")])
def test_measured_load_is_inside_the_plan(open_bus: OpenBus, mode: str, fd: bool,
                                          forces: str) -> None:
    rate, seconds = 100.0, 1.0
    p = plan(3, rate, mode, 1_000_000, data_bitrate=5_000_000 if fd else None,
             forces=forces, exact=True)  # type: ignore[arg-type]
    (planned,) = p.buses
    sender, host = open_bus(fd=fd), open_bus(fd=fd)  # who sends does not change the load
    rng = random.Random(11)
    before = host.wire_stats()
    for cycle in range(round(rate * seconds)):  # every frame at its planned rate
        for f in planned.frames:
            if cycle % round(rate / f.per_s):
                continue
            sender.send(can.Message(arbitration_id=f.cob_id, data=_payload(f, cycle, rng),
                                    is_extended_id=False, is_fd=f.fd, bitrate_switch=f.fd))
        host.advance(1.0 / rate)
    after = host.wire_stats()
    sent = sum(f.per_s for f in planned.frames) * seconds
    assert after.frames - before.frames == pytest.approx(sent)
    load = after.load_since(before)
    assert planned.load_best_pct <= load <= planned.load_worst_pct
    assert after.error_frames == 0
