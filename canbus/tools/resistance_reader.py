"""Raw resistances off any bus: the patches' own TPDOs (``eds/skin-patch.eds``).

A patch sends 0x2000, its pillar resistances as UNSIGNED16 codes (taxel*3 + pillar + 1;
pillars z, x, y; code x LSB = ohms, ``canbus.codes``: 0 short, 0xFFFE saturated, 0xFFFF
open). :class:`ResistanceReader` reads them by the EDS default mapping (3-axis: 4 codes per
TPDO in TPDO 1..7, predefined COB-IDs) and every mapping and LSB (0x2001) a master writes
or reads by SDO, as the force reader reads force nodes, and only the frames
:mod:`canbus.tools.attribution` attributes to the patch (``known``: what a host config
says, e.g. the mapping of the patch's mode). A pillar the mapping does not carry (z-only
mode) or whose PDO did not come is NaN.

Which PDOs make a sample: the patch's answer to one SYNC, judged as the host judges it
(:mod:`canbus.answers`, through :mod:`canbus.tools.patch_answers`): one sample per SYNC
cycle from the first SYNC after the patch was known, complete when every TPDO of one
answer came once and in order, and never the data of two answers.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import canopen
import numpy as np
from numpy.typing import NDArray

from canbus.codes import code_to_resistance
from canbus.patch_constants import decode_si
from canbus.pdo_codec import TpdoLayout
from canbus.tools.attribution import KnownNode
from canbus.tools.patch_answers import PatchAnswers
from canbus.tools.pdo_assembly import JoinedPdos, PdoAssembly
from canbus.tools.pdo_samples import PdoSampleReader

RESISTANCES, LSB = 0x2000, 0x2001
DEFAULT_LSB_OHM = 0.05


@dataclass(frozen=True)
class ResistanceSample:
    """One patch's pillar resistances of one SYNC cycle."""

    patch: int
    timestamp: float  # bus time of the SYNC it answers
    resistance_ohm: NDArray[np.float64]  # (9, 3) pillars z, x, y; NaN: not carried or lost
    complete: bool  # every TPDO of one answer came, once, in order (canbus.answers)
    cycle: int | None = None  # the SYNC cycle: 1 for the first SYNC read, 2, ...


class ResistanceReader(PdoSampleReader):
    """Resistance samples of the patches ``patches`` (node-IDs) on the bus it listens to;
    ``answer_orders``: node-ID -> the order a patch sends an answer's TPDOs in (a host
    config's ``answer_order``; default ascending COB-ID)."""

    def __init__(self, patches: Iterable[int], *, period_s: float | None = None,
                 known: Iterable[KnownNode] = (),
                 answer_orders: Mapping[int, str] | None = None) -> None:
        self.lsb_ohm = dict.fromkeys(patches, DEFAULT_LSB_OHM)
        self.answer_orders = dict(answer_orders or {})
        self._callbacks: tuple[Callable[[ResistanceSample], None], ...] = ()
        super().__init__(self.lsb_ohm, "skin-patch", period_s=period_s, known=known)

    def on_sample(self, callback: Callable[[ResistanceSample], None]) -> None:
        """Call ``callback(sample)`` for every sample, on the processing thread."""
        self._callbacks = (*self._callbacks, callback)

    def on_samples(self, assembly: PdoAssembly, raws: list[JoinedPdos]) -> None:
        columns = [k for k, v in enumerate(assembly.variables)
                   if v.index == RESISTANCES and 1 <= v.subindex <= 27]
        at = [assembly.variables[k].subindex - 1 for k in columns]
        values = assembly.values(raws)[:, columns]
        came = assembly.arrived(raws)[:, columns]
        ohm = np.full((len(raws), 27), np.nan)
        ohm[:, at] = np.where(came, code_to_resistance(values, self.lsb_ohm[assembly.node_id]),
                              np.nan)
        for i, raw in enumerate(raws):
            sample = ResistanceSample(raw.node_id, raw.timestamp, ohm[i].reshape(9, 3),
                                      raw.complete, raw.cycle)
            for callback in self._callbacks:
                callback(sample)

    def _assembly(self, node_id: int, layouts: Sequence[TpdoLayout],
                  od: canopen.ObjectDictionary) -> PdoAssembly:
        return PatchAnswers(node_id, layouts, od, cycles=self.cycles,
                            order=self.answer_orders.get(node_id, self.order))

    def on_observed(self, node_id: int, index: int, subindex: int, raw: bytes) -> None:
        if (index, subindex) == (LSB, 0):
            lsb = decode_si(index, subindex, raw)
            if lsb is not None and lsb > 0:
                self.lsb_ohm[node_id] = lsb
