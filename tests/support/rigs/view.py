"""A recorded host run for the view's tests: simulated patches, the host, a Recorder.

The patches answer each SYNC with the next step of a precomputed simulation (as ``skin
demo`` serves them), the host decodes and publishes force nodes, and a third bus records
every frame. The host's force frames are kept, to check what the view reads against.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from canbus.device.source import ArraySource
from canbus.master.dataplane import ForceFrame
from canbus.master.hostconfig import HostConfig, PatchConfig
from canbus.tools.recorder import Recorder
from tests.support.rigs.recorded_host import recorded_host
from tests.support.rigs.waiting import wait_until


@dataclass
class HostRun:
    path: Path
    frames: list[ForceFrame]
    config: HostConfig
    stats: dict[str, int]


def until(condition: Callable[[], bool], what: str, timeout: float = 60.0) -> None:
    wait_until(condition, what=what, timeout=timeout)


def record_host_run(path: Path, resistance_ohm: np.ndarray, node_ids: tuple[int, ...], *,
                    cycles: int, channel: str, mode: str = "xyz",
                    sync_period_ms: float = 10.0) -> HostRun:
    """Patches serving ``resistance_ohm`` (samples, patches, 9, P) in a loop and the host,
    recorded to ``path`` until every patch has ``cycles`` force frames."""
    config = HostConfig(patches=tuple(PatchConfig(n, mode=mode) for n in node_ids),
                        sync_period_ms=sync_period_ms, heartbeat_ms=200, scan_ms=100)
    with recorded_host(channel, config, ArraySource(resistance_ohm, node_ids),
                       [Recorder(path)]) as run:
        until(lambda: min(sum(f.patch == n for f in run.frames) for n in node_ids) >= cycles,
              "force frames")
    return HostRun(path, run.frames, config, run.stats)
