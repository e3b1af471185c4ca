"""The data plane's test rig: patches that answer SYNCs with chosen forces, and a data
plane that publishes to a sink bus."""

# mypy: disable-error-code="no-untyped-call"
from __future__ import annotations

from typing import Any

import can
import canopen
import numpy as np
from numpy.typing import ArrayLike

from canbus.codes import code_to_resistance
from canbus.device.patch_node import PatchNode
from canbus.master.dataplane import DataPlane, ForceFrame, PatchChannel
from canbus.master.forcenode import ForceNode
from canbus.od import load_od
from decoder.protocol import Decoded
from decoder.registry import create_decoder
from skin.benchmarks.dataplane_rigs import SinkBus
from skin.constants import DEFAULT_CONSTANTS
from skin.tripod import resistance_from_force

LSB = DEFAULT_CONSTANTS.resistance_lsb_ohm
WINDOW_S = 0.005
T0 = 1000.0  # SYNC k is sent at T0 + k / 100 on the test's clock


def load(scale: float = 1.0) -> np.ndarray:
    force = np.zeros((9, 3))
    force[:, 2] = np.linspace(0.5, 4.0, 9) * scale
    force[:, 0], force[:, 1] = 0.2 * scale, -0.15 * scale
    return force


def sync_time(cycle: int) -> float:
    return T0 + cycle / 100


class Patch:
    """A patch node that encodes chosen forces, and its force node."""

    def __init__(self, node_id: int, mode: str = "xyz") -> None:
        self.node = PatchNode(node_id, mode=mode)
        self.force_node = ForceNode(node_id + 64, node_id, heartbeat_ms=0)

    @property
    def codec(self) -> Any:
        return self.node.tpdo.codec

    def channel(self, decoder: Any) -> PatchChannel:
        return PatchChannel(self.node.node_id, self.codec, self.node.pillars, LSB, decoder,
                            self.force_node)

    @property
    def order(self) -> list[int]:
        """The TPDOs (positions in the codec) in the order the patch sends them: COB-ID."""
        return sorted(range(len(self.codec.cob_ids)), key=lambda p: int(self.codec.cob_ids[p]))

    def frames(self, force_N: ArrayLike, cycle: int, **faults: float) -> list[can.Message]:
        """The answer to SYNC ``cycle``, in sending order; ``faults``: {"t<k>": ohm} on
        pillar z."""
        r = resistance_from_force(np.asarray(force_N), DEFAULT_CONSTANTS)[:, : self.node.pillars]
        for name, ohm in faults.items():
            r[int(name[1:]), 0] = ohm
        self.node.update(r)
        return self.answer(self.codec.pack(self.node.values())[0], cycle)

    def answer(self, payloads: np.ndarray, cycle: int) -> list[can.Message]:
        """Frames of the codec's ``(PDOs, 8)`` payloads, in sending order, 0.1 ms apart."""
        t = sync_time(cycle)
        return [can.Message(timestamp=t + 1e-4 * (k + 1), arbitration_id=int(self.codec.cob_ids[p]),
                            data=payloads[p, :self.codec.sizes[p]].tobytes(), is_extended_id=False)
                for k, p in enumerate(self.order)]

    def expected(self, decoder: Any) -> Decoded:
        """What the decoder makes of the codes the node sent last."""
        r = code_to_resistance(self.node.codes[:, : self.node.pillars], LSB)
        decoded: Decoded = decoder.decode(r[None])
        return decoded

    def carried(self, place: int) -> list[int]:
        """The taxels the ``place``-th frame of an answer (0-based) carries values of."""
        layout = self.codec.layouts[self.order[place]]
        return sorted({(e.subindex - 1) // 3 for e in layout.entries})


class Host:
    """A data plane publishing to a sink, two patches, and what it published."""

    def __init__(self, decoder: Any = None, *, mode: str = "xyz") -> None:
        self.decoder = decoder or create_decoder("analytic")
        self.sink = SinkBus()
        self.network = canopen.Network(self.sink)
        self.patches = [Patch(1, mode), Patch(2, mode)]
        for patch in self.patches:
            patch.force_node.attach(self.network)
            patch.force_node.start()
        self.reset()

    def reset(self) -> None:
        """A new data plane for the same patches, nothing published yet."""
        self.plane = DataPlane(self.sink, sync_window_s=WINDOW_S, background=False)
        for patch in self.patches:
            self.plane.add_channel(patch.channel(self.decoder))
        self.sink.sent.clear()
        self.out: list[ForceFrame] = []
        self.plane.subscribe(self.out.extend)

    def feed(self, frames: list[can.Message]) -> None:
        for msg in frames:
            self.plane.on_message_received(msg)

    def sync(self, cycle: int) -> None:
        self.plane.on_sync(cycle, cycle % 240 + 1, sync_time(cycle))

    def published(self, force_node: int) -> dict[int, bytes]:
        cobs = self.patches[force_node - 65].force_node.cob_ids()
        return {cob: data for cob, data in self.sink.sent if cob in cobs and cob < 0x580}

    def close(self) -> None:
        self.plane.stop()
        for patch in self.patches:
            patch.force_node.detach()
        self.sink.shutdown()


def consume(frames: dict[int, bytes], node_id: int = 65) -> tuple[list[int], int]:
    """A canopen master decoding a force node's TPDOs with eds/skin-forces.eds."""
    node = canopen.Network().add_node(canopen.RemoteNode(node_id, load_od("skin-forces", node_id)))
    node.tpdo.read(from_od=True)
    values: dict[tuple[int, int], int] = {}
    for pdo in node.tpdo.values():
        pdo.on_message(pdo.cob_id, bytearray(frames[pdo.cob_id]), 0.0)
        values.update({(v.index, v.subindex): v.raw for v in pdo})
    return [values[(0x2000, k)] for k in range(1, 28)], values[(0x2005, 0)]


def mN(force_N: np.ndarray) -> list[int]:
    return [int(v) for v in np.rint(force_N * 1000).reshape(27)]
