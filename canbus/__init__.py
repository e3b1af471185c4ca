"""The wire: CANopen patches, the host manager, the data plane and the bus tools.

Layout: ``canbus.device`` (a patch as a CANopen node, and a server of many),
``canbus.master`` (the live host manager, its config, the data plane, the force nodes),
``canbus.offline`` (recordings decoded by the host without a bus), ``canbus.tools``
(sniffer, recorder, replay, pcap, EDS checker), ``canbus.timed`` (the timed bus) and,
beside them, the wire-level modules they share: ``codes``, ``pdo_codec``, ``txmessage``,
``busload``, ``od``. The names below are imported on first use, so ``import canbus``
stays cheap and puts nothing in ``sys.modules`` but itself and what it imports.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from canbus.busload import plan
    from canbus.device.patch_node import PatchNode
    from canbus.device.patch_server import PatchServer
    from canbus.master.dataplane import DataPlane, ForceFrame, PatchChannel
    from canbus.master.forcenode import ForceNode
    from canbus.master.host import HostManager, PatchHealth
    from canbus.master.hostconfig import HostConfig, PatchConfig, load_host_config
    from canbus.master.rawsample import RawSample
    from canbus.tools.recorder import Recorder
    from canbus.tools.recording import Recording
    from canbus.tools.replay import Replayer
    from canbus.tools.sniffer import Sniffer

_PUBLIC = {
    "plan": "canbus.busload",
    "PatchNode": "canbus.device.patch_node", "PatchServer": "canbus.device.patch_server",
    "DataPlane": "canbus.master.dataplane", "ForceFrame": "canbus.master.dataplane",
    "PatchChannel": "canbus.master.dataplane", "ForceNode": "canbus.master.forcenode",
    "HostManager": "canbus.master.host", "PatchHealth": "canbus.master.host",
    "HostConfig": "canbus.master.hostconfig", "PatchConfig": "canbus.master.hostconfig",
    "load_host_config": "canbus.master.hostconfig", "RawSample": "canbus.master.rawsample",
    "Recorder": "canbus.tools.recorder", "Recording": "canbus.tools.recording",
    "Replayer": "canbus.tools.replay", "Sniffer": "canbus.tools.sniffer",
}
__all__ = [
    "DataPlane", "ForceFrame", "ForceNode", "HostConfig", "HostManager", "PatchChannel",
    "PatchConfig", "PatchHealth", "PatchNode", "PatchServer", "RawSample", "Recorder",
    "Recording", "Replayer", "Sniffer", "load_host_config", "plan",
]


def __getattr__(name: str) -> Any:
    if name in _PUBLIC:
        return getattr(importlib.import_module(_PUBLIC[name]), name)
    raise AttributeError(f"module 'canbus' has no attribute {name!r}")
