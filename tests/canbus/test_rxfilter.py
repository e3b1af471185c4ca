"""Receive filters: own frames and acceptance lists, in the kernel on udp_multicast.

The BPF program is run here by an independent interpreter of the classic BPF instructions it
uses, over python-can's own udp_multicast datagrams (hypothesis); then on real sockets.
"""

from __future__ import annotations

import struct
import sys
from collections.abc import Iterator

import can
import pytest
from can.interfaces.udp_multicast.utils import pack_message
from hypothesis import given, settings
from hypothesis import strategies as st

from canbus.rxfilter import (
    OwnFrameGate,
    compile_filter,
    echoes_own_frames,
    layout_known,
    receive_filter,
)

UDP_HEADER = bytes(8)


def run_bpf(program: list[bytes], packet: bytes) -> int:
    """A classic BPF interpreter for the instructions the filter uses (LD B/H ABS, JEQ, JGE,
    JGT, JA, TAX, TXA, RET K); an out-of-packet load returns 0, as the kernel does."""
    ops = [struct.unpack("HBBI", ins) for ins in program]
    a = x = pc = 0
    while True:
        code, jt, jf, k = ops[pc]
        pc += 1
        if code == 0x30:  # ld b[k]
            if k >= len(packet):
                return 0
            a = packet[k]
        elif code == 0x28:  # ld h[k]
            if k + 2 > len(packet):
                return 0
            a = int.from_bytes(packet[k:k + 2], "big")
        elif code in (0x15, 0x35, 0x25):  # jeq, jge, jgt
            taken = {0x15: a == k, 0x35: a >= k, 0x25: a > k}[code]
            pc += jt if taken else jf
        elif code == 0x05:  # ja
            pc += k
        elif code == 0x07:  # tax
            x = a
        elif code == 0x87:  # txa
            a = x
        elif code == 0x06:  # ret k
            return k
        else:
            raise AssertionError(f"unexpected instruction {code:#x}")


def passes(program: list[bytes], msg: can.Message) -> bool:
    return run_bpf(program, UDP_HEADER + pack_message(msg)) != 0


ids = st.integers(0, 0x7FF)


@settings(max_examples=300, deadline=None)
@given(drop=st.frozensets(ids, max_size=40), accept=st.none() | st.frozensets(ids, max_size=40),
       cob_id=ids, extended=st.booleans(), remote=st.booleans(),
       data=st.binary(max_size=8))
def test_the_program_drops_exactly_claimed_and_unaccepted_data_frames(
        drop: frozenset[int], accept: frozenset[int] | None, cob_id: int, extended: bool,
        remote: bool, data: bytes) -> None:
    program = compile_filter(drop, accept)
    msg = can.Message(arbitration_id=cob_id, is_extended_id=extended, is_remote_frame=remote,
                      data=b"" if remote else data, dlc=len(data))
    plain = not extended and not remote  # what the filter reads; it passes anything else
    dropped = plain and (cob_id in drop or (accept is not None and cob_id not in accept))
    assert passes(program, msg) is not dropped


def test_the_program_passes_what_it_cannot_read() -> None:
    program = compile_filter({0x181}, {0x080})
    assert passes(program, can.Message(arbitration_id=0x181, is_extended_id=False,
                                       timestamp=5))  # an int timestamp: another layout
    assert passes(program, can.Message(arbitration_id=0x12345, is_extended_id=True))
    assert passes(program, can.Message(arbitration_id=0x181, is_error_frame=True,
                                       is_extended_id=False))
    assert run_bpf(program, UDP_HEADER + b"\x81\xa1x") != 0  # not python-can's datagram
    assert not passes(program, can.Message(arbitration_id=0x181, is_extended_id=False))


def test_long_lists_still_assemble() -> None:
    every_other = set(range(0, 0x800, 2))  # 1024 ranges of one: far jumps go by JA
    program = compile_filter(every_other - {0}, every_other)
    assert passes(program, can.Message(arbitration_id=0, is_extended_id=False))
    assert not passes(program, can.Message(arbitration_id=2, is_extended_id=False))
    assert not passes(program, can.Message(arbitration_id=3, is_extended_id=False))


def test_claims_name_eleven_bit_cob_ids_and_never_nmt() -> None:
    with can.Bus(interface="virtual", channel="rxfilter-claims") as bus:
        own = receive_filter(bus)
        assert receive_filter(bus) is own and not echoes_own_frames(bus)
        with pytest.raises(ValueError, match="0x000"):
            own.claim(object(), [0x000])
        with pytest.raises(ValueError, match="0x800"):
            own.claim(object(), [0x800])
        owner = object()
        own.claim(owner, [0x181])
        own.claim(owner, [0x182])  # replaces the owner's claim
        assert own.cob_ids == {0x182} and not own.in_kernel
        # virtual returns no frame to its sender unasked: nothing is "own" there
        assert not own.is_own(can.Message(arbitration_id=0x182, is_extended_id=False))


@pytest.fixture
def udp_pair(udp_channel: str, udp_port: int) -> Iterator[tuple[can.BusABC, can.BusABC]]:
    a = can.Bus(interface="udp_multicast", channel=udp_channel, port=udp_port)
    b = can.Bus(interface="udp_multicast", channel=udp_channel, port=udp_port)
    yield a, b
    a.shutdown()
    b.shutdown()


def _drain(bus: can.BusABC) -> list[int]:
    got = []
    while (msg := bus.recv(0.2)) is not None:
        got.append(msg.arbitration_id)
    return got


def _send(bus: can.BusABC, *cob_ids: int) -> None:
    for cob_id in cob_ids:
        bus.send(can.Message(arbitration_id=cob_id, is_extended_id=False, data=b"\x01"))


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a Linux socket filter")
def test_udp_multicast_echoes_are_dropped_in_the_kernel(
        udp_pair: tuple[can.BusABC, can.BusABC]) -> None:
    a, b = udp_pair
    assert echoes_own_frames(a) and layout_known()
    _send(a, 0x181, 0x201)
    assert _drain(a) == [0x181, 0x201]  # the echo of a's own frames, unasked
    assert _drain(b) == [0x181, 0x201]
    own = receive_filter(a)
    owner = object()
    own.claim(owner, [0x181, 0x201, 0x701])
    assert own.in_kernel
    _send(a, 0x181, 0x201, 0x701, 0x182)
    _send(b, 0x080)
    assert _drain(a) == [0x182, 0x080]
    assert _drain(b) == [0x181, 0x201, 0x701, 0x182, 0x080]  # the others see everything
    own.accept_only([0x000, 0x080])  # what a device consumes, say
    _send(b, 0x080, 0x1C1, 0x000, 0x601)
    assert _drain(a) == [0x080, 0x000]
    own.accept_only(None)
    own.release(owner)
    assert not own.in_kernel
    _send(a, 0x181)
    assert _drain(a) == [0x181]


def test_the_gate_drops_own_frames_where_the_kernel_cannot(
        udp_pair: tuple[can.BusABC, can.BusABC], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("canbus.rxfilter._install", lambda *args: False)
    a, _ = udp_pair
    own = receive_filter(a)
    owner = object()
    own.claim(owner, [0x181])
    assert not own.in_kernel
    seen: list[int] = []

    class Collect(can.Listener):
        def on_message_received(self, msg: can.Message) -> None:
            seen.append(msg.arbitration_id)

    gate = OwnFrameGate(Collect(), own)
    for cob_id in (0x181, 0x182):
        gate.on_message_received(can.Message(arbitration_id=cob_id, is_extended_id=False))
    gate.on_message_received(can.Message(arbitration_id=0x181, is_extended_id=True))
    own.release(owner)
    assert seen == [0x182, 0x181] and gate.dropped == 1


def test_the_sniffer_leaves_its_own_process_echoes_out_of_its_counts(
        udp_pair: tuple[can.BusABC, can.BusABC]) -> None:
    from canbus.tools.sniffer import Sniffer

    a, _ = udp_pair
    own, owner = receive_filter(a), object()
    own.claim(owner, [0x181])
    sniffer = Sniffer(own=own)
    for cob_id in (0x181, 0x182, 0x181):
        sniffer.on_message_received(can.Message(arbitration_id=cob_id, is_extended_id=False,
                                                data=bytes(8), timestamp=1.0))
    own.release(owner)
    snap = sniffer.snapshot()
    assert (snap.frames, sniffer.own_frames) == (1, 2)
    assert [row.cob_id for row in snap.rows] == [0x182]
