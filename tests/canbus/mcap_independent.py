"""What a reader independent of canskin gets from an .mcap: the ``mcap`` library with its
ROS 2 decoder (mcap-ros2-support), reading the schemas the file carries, and each
PointCloud2's own field table; no canskin code is used."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def decoded(path: Path) -> list[tuple[str, Any]]:
    """(topic, decoded message) of every message, in log time order."""
    with path.open("rb") as file:
        reader = make_reader(file, decoder_factories=[DecoderFactory()])
        return [(c.topic, d) for _s, c, _m, d in reader.iter_decoded_messages()]


def column(cloud: Any, name: str, dtype: str) -> np.ndarray:
    """One field of every point of a PointCloud2, by the cloud's own field table."""
    offset = {f.name: f.offset for f in cloud.fields}[name]
    size = np.dtype(dtype).itemsize
    points = np.frombuffer(bytes(cloud.data), np.uint8).reshape(cloud.width, cloud.point_step)
    return points[:, offset:offset + size].copy().view(dtype).ravel()


@dataclass(frozen=True)
class Sample:
    patch: int
    cycle: int
    time_s: float
    force_N: np.ndarray  # (9, 3)
    valid: list[bool]
    frame_id: str


def samples(path: Path) -> dict[tuple[int, int], Sample]:
    """Every patch's taxel cloud, by (patch, cycle)."""
    out = {}
    for topic, cloud in decoded(path):
        if topic.startswith("/skin/") and topic.endswith("/taxels"):
            force = np.stack([column(cloud, a, "<f8") for a in ("fx", "fy", "fz")], axis=1)
            sample = Sample(int(column(cloud, "patch", "u1")[0]),
                            int(column(cloud, "cycle", "<u4")[0]),
                            float(column(cloud, "time_s", "<f8")[0]), force,
                            column(cloud, "valid", "u1").astype(bool).tolist(),
                            cloud.header.frame_id)
            out[(sample.patch, sample.cycle)] = sample
    return out


def can_frames(path: Path) -> list[tuple[int, bool, bool, bytes]]:
    """(id, extended, remote, data) of every classic frame on /can/frames."""
    return [(f.id, f.is_extended, f.is_rtr, bytes(f.data)[:0 if f.is_rtr else f.dlc])
            for topic, f in decoded(path) if topic == "/can/frames"]
