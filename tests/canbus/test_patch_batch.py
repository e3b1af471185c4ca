"""The patch server's batched path equals each node's own: codes, status, EMCY, TPDO bytes."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from canbus import codes
from canbus.device.nmt_slave import OPERATIONAL, PRE_OPERATIONAL
from canbus.device.patch_node import (
    PatchNode,
    batch_frames_on_event,
    batch_frames_on_sync,
    batch_update,
)
from canbus.pdo_codec import TPDO_MAP
from tests.support.rigs.waiting import wait_until

LSB = 0.05
_EMCY = struct.Struct("<HBBB3x")


class _Network:
    """Records what a node's fault reporter sends."""

    def __init__(self) -> None:
        self.sent: list[tuple[int, bytes]] = []

    def send_message(self, cob_id: int, data: bytes) -> None:
        self.sent.append((cob_id, bytes(data)))


def _nodes(state: int = OPERATIONAL) -> list[PatchNode]:
    """xyz, xyz remapped (TPDO 7 also carries 0x2004:5 and 0x1001), z-only, xyz."""
    nodes = [PatchNode(1), PatchNode(2), PatchNode(3, mode="z"), PatchNode(4)]
    remapped = nodes[1]
    entries = [0x20001910, 0x20001A10, 0x20001B10, 0x20040508, 0x10010008]
    remapped.store.store(TPDO_MAP + 6, 0, len(entries))
    for s, raw in enumerate(entries, start=1):
        remapped.store.store(TPDO_MAP + 6, s, raw)
    remapped.tpdo.reset()
    for node in nodes:
        node.network = _Network()  # type: ignore[assignment]
        node.nmt.state = state
    return nodes


def _samples(width: int, count: int = 6) -> np.ndarray:
    """(count, 4, 9, width) ohms with faults coming and going on nodes 2 and 3."""
    rng = np.random.default_rng(width)
    r = rng.uniform(900.0, 1500.0, (count, 4, 9, width))
    r[1, 1, 4, 0] = np.inf  # open
    r[2, 1, 4, 0] = np.inf
    r[2, 2, 0, 0] = 0.0  # short
    r[3, 2, 7, -1] = 1e6  # saturated
    r[4, 1, 4, 0] = -1.0  # short again, other code
    return r


def _reference_update(state: dict[int, np.ndarray], node: PatchNode, r: np.ndarray,
                      sent: list[tuple[int, bytes]]) -> None:
    """PatchNode.update as specified: codes, status over the measured pillars, EMCY."""
    width = r.shape[1]
    new = state[node.node_id].copy()
    new[:, :width] = codes.resistance_to_code(r, LSB)
    status = codes.taxel_status(new, min(width, node.pillars))
    old = state.setdefault(-node.node_id, np.zeros(9, dtype=np.uint8))
    register = 0x81 if status.any() else 0
    for taxel in np.flatnonzero(status != old).tolist():
        code = 0x5000 if status[taxel] else 0x0000
        sent.append((0x80 + node.node_id, _EMCY.pack(code, register, taxel, int(status[taxel]))))
    state[node.node_id], state[-node.node_id] = new, status


@pytest.mark.parametrize("width", [1, 3])
def test_batch_update_equals_each_node_updated_alone(width: int) -> None:
    nodes = _nodes(PRE_OPERATIONAL)
    state = {n.node_id: np.full((9, 3), codes.OPEN, dtype=np.uint16) for n in nodes}
    expected: list[tuple[int, bytes]] = []
    for sample in _samples(width):
        batch_update(nodes, sample)
        for node, r in zip(nodes, sample, strict=True):
            _reference_update(state, node, r, expected)
            np.testing.assert_array_equal(node.codes, state[node.node_id])
            np.testing.assert_array_equal(node.faults.status, state[-node.node_id])
    sent = [f for node in nodes for f in node.network.sent]  # type: ignore[union-attr]
    assert sorted(sent) == sorted(expected)
    # every fault and recovery above; with 3 pillars the z-only patch's saturated pillar
    # is its unmeasured y, no fault
    assert len(expected) == {1: 8, 3: 6}[width]


def _reference_frames(node: PatchNode) -> list[tuple[int, bytes]]:
    """Every valid TPDO of the node packed from ``values()``, one PDO at a time, in the
    order a node's queued frames leave on a CAN bus: ascending COB-ID."""
    codec = node.tpdo.codec
    payloads = codec.pack(node.values())[0]
    return sorted((int(cob), payloads[p, :size].tobytes())
                  for p, (cob, size) in enumerate(zip(codec.cob_ids, codec.sizes, strict=True)))


def test_batch_frames_equal_each_node_packed_alone() -> None:
    nodes = _nodes()
    nodes[0].nmt.state = PRE_OPERATIONAL  # sends nothing
    for k, sample in enumerate(_samples(3)):
        batch_update(nodes, sample)
        expected = [f for node in nodes[1:] for f in _reference_frames(node)]
        assert batch_frames_on_sync(nodes, k + 1) == expected
        assert nodes[3].frames_on_sync(k + 1) == _reference_frames(nodes[3])
    assert any(payload[-2:] != b"\x00\x00" for cob, payload in expected if cob == 0x182)


def test_batch_frames_on_event_follow_each_node_schedule() -> None:
    nodes = _nodes()
    batch_update(nodes, _samples(3)[0])
    for node in nodes:  # TPDO 1 event-driven with a 10 ms timer; the rest stay on SYNC
        node.store.store(0x1800, 2, 254)
        node.store.store(0x1800, 5, 10)
        node.tpdo.reset()
    first = batch_frames_on_event(nodes, 1.0)
    assert first == [_reference_frames(node)[0] for node in nodes]
    assert batch_frames_on_event(nodes, 1.005) == []
    assert len(batch_frames_on_event(nodes, 1.010)) == len(nodes)


def test_a_mapping_written_while_another_thread_builds_the_codec_is_not_lost(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A patch server's sample thread may build a node's codec while a master's SDO write
    changes the mapping on the bus's thread: the write must win, not the stale build."""
    import threading

    from canbus.device import tpdo as tpdo_module

    node = PatchNode(1)
    assert len(node.tpdo.codec.layouts) == 7
    node.tpdo.reset()
    read, started, go = tpdo_module.read_layouts, threading.Event(), threading.Event()

    def slow_read(*args: object, **kwargs: object) -> object:
        layouts = read(*args, **kwargs)  # type: ignore[arg-type]
        started.set()
        go.wait(5.0)
        return layouts

    monkeypatch.setattr(tpdo_module, "read_layouts", slow_read)
    builder = threading.Thread(target=lambda: node.tpdo.codec)
    builder.start()
    assert started.wait(5.0)
    cob = int(node.store.value(0x1806, 1))
    writer = threading.Thread(target=lambda: node.store.set_data(
        0x1806, 1, struct.pack("<I", cob | 0x8000_0000)))  # TPDO 7 invalid, as a master does
    writer.start()
    wait_until(lambda: int(node.store.value(0x1806, 1)) == cob | 0x8000_0000,
               what="the write landed (its invalidation waits for the build)")
    go.set()
    builder.join(5.0)
    writer.join(5.0)
    monkeypatch.setattr(tpdo_module, "read_layouts", read)
    assert len(node.tpdo.codec.layouts) == 6
