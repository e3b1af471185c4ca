"""PdoRouter: the data plane alone takes its patches' PDOs; everything else goes on."""

from __future__ import annotations

import can
import pytest

from canbus.device.patch_node import PatchNode
from canbus.master.dataplane import DataPlane, PatchChannel
from canbus.master.forcenode import ForceNode
from canbus.master.pdo_router import PdoRouter
from decoder.registry import create_decoder
from skin.benchmarks.dataplane_rigs import SinkBus


class _Seen(can.Listener):
    def __init__(self, handles_errors: bool = True) -> None:
        self.frames: list[int] = []
        self.errors: list[Exception] = []
        self.stopped = False
        self.handles_errors = handles_errors

    def on_message_received(self, msg: can.Message) -> None:
        self.frames.append(msg.arbitration_id)

    def on_error(self, exc: Exception) -> None:
        if not self.handles_errors:
            raise NotImplementedError
        self.errors.append(exc)

    def stop(self) -> None:
        self.stopped = True


@pytest.fixture
def plane() -> DataPlane:
    node = PatchNode(3)
    plane = DataPlane(SinkBus(), sync_window_s=0.0, background=False)
    plane.add_channel(PatchChannel(3, node.tpdo.codec, 3, 0.05, create_decoder("analytic"),
                                   ForceNode(67, 3, heartbeat_ms=0)))
    return plane


def _frame(cob: int, **flags: bool) -> can.Message:
    return can.Message(arbitration_id=cob, data=bytes(8), is_extended_id=False, **flags)


def test_patch_pdos_reach_the_data_plane_only(plane: DataPlane) -> None:
    first, second = _Seen(), _Seen()
    router = PdoRouter(plane, [first, second])
    for cob in (0x183, 0x080, 0x283, 0x703, 0x184, 0x583):
        router.on_message_received(_frame(cob))
    router.on_message_received(_frame(0x383, is_remote_frame=True))
    assert first.frames == second.frames == [0x080, 0x703, 0x184, 0x583, 0x383]
    assert plane.stats.frames_in == 2
    # SYNC, a heartbeat, an SDO answer: the bus's own; node 4's PDO, a remote frame: unknown
    assert (plane.stats.bus_frames, plane.stats.unknown_frames) == (3, 2)


def test_errors_are_handled_as_the_notifier_would(plane: DataPlane) -> None:
    handler, bystander = _Seen(), _Seen(handles_errors=False)
    PdoRouter(plane, [bystander, handler]).on_error(err := OSError("bus gone"))
    assert handler.errors == [err]
    with pytest.raises(NotImplementedError):  # nobody handled it: the notifier re-raises
        PdoRouter(plane, [bystander]).on_error(OSError("bus gone"))


def test_stop_stops_the_others_then_the_data_plane(plane: DataPlane,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    order: list[str] = []
    other = _Seen()
    monkeypatch.setattr(other, "stop", lambda: order.append("other"))
    monkeypatch.setattr(plane, "stop", lambda: order.append("data plane"))
    PdoRouter(plane, [other]).stop()
    assert order == ["other", "data plane"]
