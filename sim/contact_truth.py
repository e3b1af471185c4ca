"""The truth of contact: net force, torque, centre of pressure and slip of the true loads.

The same summary the host computes from decoded forces (:mod:`skin.contact`), here from
the simulator's true taxel forces (before crosstalk), with every taxel valid and every
loaded one in contact (``taxel_contact_N`` = 0); in contact by the same onset and
release thresholds. Slip is not judged from the forces: it is what the loads did
(:attr:`sim.simulator.Frame.slip`: the ``slide`` sphere whenever it touches, the ``stick_slip``
load in its slip phase), counted while the patch is in contact.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sim.scene import Scene
from sim.simulator import Frame
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.contact import ContactParams, PatchGeometry, summarize
from skin.contact_state import ContactBatch, track


@dataclass(frozen=True)
class TrueContact:
    """One patch's true contact over ``n`` steps."""

    node_id: int
    batch: ContactBatch  # net force, torque, CoP, in contact (the summary of the true loads)
    slip: NDArray[np.bool_]  # (n,) the load slides over the patch while it is in contact

    @property
    def slip_onsets(self) -> NDArray[np.intp]:
        """Steps at which the patch begins to slip."""
        s = self.slip.astype(np.int8)
        return np.flatnonzero(np.diff(s, prepend=0) == 1)


def true_contact(frame: Frame, scene: Scene, params: ContactParams | None = None, *,
                 constants: SensorConstants = DEFAULT_CONSTANTS) -> list[TrueContact]:
    """The true contact of every patch of ``scene`` over ``frame``'s steps, in node order."""
    p = dataclasses.replace(params or ContactParams(), taxel_contact_N=0.0)
    out = []
    for i, patch in enumerate(scene.patches):
        force = frame.force_N[:, i]
        geometry = PatchGeometry(constants.taxel_pitch_m, patch.position_m)
        instant = summarize(force, np.ones(force.shape[:2], dtype=bool), geometry=geometry,
                            params=p)
        _, batch = track(instant, p)
        out.append(TrueContact(patch.node_id, batch, frame.slip[:, i] & batch.in_contact))
    return out
