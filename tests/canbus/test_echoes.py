"""The echo ledger tells the echoes of a process's own frames from another node's, however the
sends, the echoes and the other node's frames interleave: exactly the other node's frames
are found, the same bytes included."""

from __future__ import annotations

from collections import Counter, deque

from hypothesis import given, settings
from hypothesis import strategies as st

from canbus.echoes import ECHO_WAIT_S, EchoLedger

FORCE_NODES = range(65, 77)  # 12 force nodes: the boot-ups of 8 or more interleave
HEARTBEATS = [0x700 + node for node in FORCE_NODES]
BOOTUP, PRE_OPERATIONAL, OPERATIONAL = b"\x00", b"\x7f", b"\x05"
Frame = tuple[int, bytes]


def _own_frames(beats: int) -> dict[int, deque[bytes]]:
    """Each force node's frames in the order it sends them: boot-up, its first heartbeat
    (pre-operational), then ``beats`` operational heartbeats."""
    return {cob_id: deque([BOOTUP, PRE_OPERATIONAL, *[OPERATIONAL] * beats])
            for cob_id in HEARTBEATS}


@settings(max_examples=100)
@given(data=st.data(), beats=st.integers(0, 3),
       foreign=st.lists(st.tuples(st.sampled_from(HEARTBEATS),
                                  st.sampled_from([BOOTUP, PRE_OPERATIONAL, OPERATIONAL])),
                        max_size=4))
def test_exactly_the_frames_the_process_did_not_send_are_found(
        data: st.DataObject, beats: int, foreign: list[Frame]) -> None:
    ledger = EchoLedger(echoes=True)
    ledger.audit(HEARTBEATS)
    unsent = _own_frames(beats)
    in_flight: list[Frame] = []  # sent, its echo not back yet: echoes come in any order
    arriving = list(foreign)
    found: list[Frame] = []
    while any(unsent.values()) or in_flight or arriving:
        step = data.draw(st.sampled_from(
            [("send", cob_id) for cob_id, frames in unsent.items() if frames]
            + [("echo", k) for k in range(len(in_flight))]
            + [("foreign", k) for k in range(len(arriving))]))
        if step[0] == "send":
            frame = (step[1], unsent[step[1]].popleft())
            ledger.sending(*frame)
            in_flight.append(frame)
            continue
        frame = in_flight.pop(step[1]) if step[0] == "echo" else arriving.pop(step[1])
        if not ledger.is_echo(*frame):
            found.append(frame)
    assert Counter(found) == Counter(foreign)


def test_a_bus_that_does_not_echo_hands_over_only_other_nodes_frames() -> None:
    ledger = EchoLedger(echoes=False)
    ledger.audit([0x748])
    ledger.sending(0x748, OPERATIONAL)
    assert not ledger.is_echo(0x748, OPERATIONAL)


def test_only_audited_cob_ids_are_noted_until_forgotten() -> None:
    ledger = EchoLedger(echoes=True)
    ledger.sending(0x748, OPERATIONAL)  # not audited: not noted
    assert not ledger.is_echo(0x748, OPERATIONAL)
    ledger.audit([0x748])
    ledger.sending(0x748, OPERATIONAL)
    ledger.forget([0x748])
    assert not ledger.is_echo(0x748, OPERATIONAL)


def test_a_lost_echo_hides_one_frame_of_another_node_and_only_for_a_while() -> None:
    now = [0.0]
    ledger = EchoLedger(echoes=True, clock=lambda: now[0])
    ledger.audit([0x748])
    ledger.sending(0x748, OPERATIONAL)  # its echo is lost (a full receive buffer)
    now[0] = 1.0
    assert ledger.is_echo(0x748, OPERATIONAL)  # the other node's first heartbeat
    assert not ledger.is_echo(0x748, OPERATIONAL)  # its second is found
    ledger.sending(0x748, OPERATIONAL)  # lost as well
    now[0] += ECHO_WAIT_S + 1.0
    assert not ledger.is_echo(0x748, OPERATIONAL)
