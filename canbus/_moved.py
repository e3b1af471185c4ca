"""Module paths from before canbus/ had subpackages, kept working: ``import canbus.host``
and ``from canbus.dataplane import DataPlane`` still find the module where it lives now
(with a DeprecationWarning on first use). The old ``canbus.device`` module is the
``canbus.device`` package now, which exports what it held."""

from __future__ import annotations

import importlib
import sys
import types
import warnings
from typing import Any

MOVED = {
    **{name: f"canbus.device.{name}" for name in (
        "patch_node", "patch_server", "object_store", "sdo_server", "nmt_slave", "heartbeat",
        "emcy", "tpdo", "source")},
    **{name: f"canbus.master.{name}" for name in (
        "host", "hostconfig", "discovery", "patch_setup", "liveness", "sync_producer",
        "dataplane", "forcenode", "fanout", "baseline", "dataplane_bench")},
    **{name: f"canbus.tools.{name}" for name in (
        "sniffer", "services", "pdo_names", "recorder", "replay", "pcap", "edscheck")},
}


class _MovedModule(types.ModuleType):
    """Stands in for a moved module: the first attribute read imports the real one."""

    def __init__(self, name: str, target: str) -> None:
        super().__init__(name, f"moved to {target}")
        self._target = target

    def __getattr__(self, attr: str) -> Any:
        if attr.startswith("__"):
            raise AttributeError(attr)
        warnings.warn(f"{self.__name__} is now {self._target}", DeprecationWarning,
                      stacklevel=2)
        return getattr(importlib.import_module(self._target), attr)


def install(package: types.ModuleType) -> None:
    for short, target in MOVED.items():
        name = f"{package.__name__}.{short}"
        if name not in sys.modules:
            alias = _MovedModule(name, target)
            sys.modules[name] = alias
            setattr(package, short, alias)
