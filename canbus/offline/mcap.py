"""MCAP recordings and the host: where a config places its patches (an .mcap's
``/tf_static``), a recording's frames and the samples decoded from them written as one
.mcap (``skin decode -o F.mcap``), and the samples of an .mcap as the host's
:class:`~canbus.master.channel.ForceFrame` (:func:`read_forces`). docs/mcap.md."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from canbus.master.channel import ForceFrame
from canbus.master.hostconfig import HostConfig
from canbus.tools import mcap_messages as m
from canbus.tools.mcap_reader import taxel_points
from canbus.tools.mcap_writer import McapSegment
from canbus.tools.recording import Recording
from skin.constants import DEFAULT_CONSTANTS
from skin.errors import SkinError
from skin.inputs.outputs import create_beside, discard, put_in_place, write_error


def placements(config: HostConfig) -> list[m.Placement]:
    """Where the host config puts each patch (``position_m``, ``orientation_deg``, the
    pitch of its ``constants``): an .mcap's /tf_static and taxel positions."""
    return [m.Placement(p.node_id, p.position_m or (0.0, 0.0), p.orientation_deg,
                        (p.constants or DEFAULT_CONSTANTS).taxel_pitch_m)
            for p in config.patches]


def write_decoded(output: str | os.PathLike[str], recording: str | os.PathLike[str],
                  samples: list[ForceFrame], config: HostConfig) -> None:
    """An .mcap of ``recording``'s frames and the ``samples`` decoded from them, put under
    ``output`` only once complete (an error leaves nothing there)."""
    final = Path(output)
    fd, tmp = create_beside(final, ".mcap")
    os.close(fd)
    try:
        segment = McapSegment(Path(tmp), None, placements(config))
        try:
            with Recording(recording) as frames:
                for msg in frames:
                    segment.add_frame(msg)
            for sample in samples:
                segment.write_forces(sample)
        finally:
            segment.close()
        put_in_place(tmp, final)
    except BaseException as err:
        discard(tmp)
        if isinstance(err, OSError) and not isinstance(err, SkinError):
            raise write_error(final, err) from err
        raise


def read_forces(path: str | os.PathLike[str]) -> Iterator[ForceFrame]:
    """Every force sample of an MCAP recording, as the host's API gave it (``contact`` is
    None: the contact summary is on its own topics, docs/mcap.md). EOFError at the end of
    a file whose writer did not finish it, after every sample of its whole chunks."""
    for points in taxel_points(os.fspath(path)):
        yield force_frame(points)


def force_frame(points: np.ndarray[Any, Any]) -> ForceFrame:
    """The sample one taxel cloud holds."""
    first = points[0]
    flags = int(first["flags"])
    force = np.stack([points["fx"], points["fy"], points["fz"]], axis=1).astype(np.float64)
    return ForceFrame(patch=int(first["patch"]), force_node=int(first["force_node"]),
                      cycle=int(first["cycle"]), sync_counter=int(first["sync_counter"]),
                      timestamp=float(first["time_s"]), force_N=force,
                      valid=points["valid"].astype(bool), reason=points["reason"].copy(),
                      complete=bool(flags & m.COMPLETE), published=bool(flags & m.PUBLISHED))
