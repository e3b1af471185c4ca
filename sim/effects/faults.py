"""faults: broken pillars as the node reports them (after readout and the ADC).

open: +inf (the ADC's over-range/open code when ``noise`` is listed); short:
0 Ω; stuck: the value of the first faulty step, repeated; saturated: the ADC's
full-scale code. Faults act on the reported channel: under ``passive_matrix``
the fault does not re-route its neighbours' sneak paths.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from sim.params import build, non_negative, one_of
from skin.constants import PILLARS, SensorConstants
from skin.errors import ConfigError
from skin.inputs import fields

F64 = NDArray[np.float64]
FAULT_KINDS = ("open", "short", "stuck", "saturated")


@dataclass(frozen=True)
class FaultSpec:
    node_id: int
    taxel: int
    pillar: str = "z"
    kind: str = "open"
    from_s: float = 0.0

    RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "taxel": (0, 8), "from_s": (0.0, 1e9)}  # node_id: a node-ID (sim.params.build)

    def check(self, where: str) -> None:
        if not 0 <= self.taxel <= 8:
            raise ConfigError(f"{where}.taxel", f"must be in 0..8, got {self.taxel}")
        one_of(self.pillar, PILLARS, f"{where}.pillar", "pillar")
        one_of(self.kind, FAULT_KINDS, f"{where}.kind", "fault")
        non_negative(self.from_s, f"{where}.from_s")


@dataclass(frozen=True)
class FaultsParams:
    pillars: tuple[FaultSpec, ...] = ()

    def check(self, where: str) -> None:
        return None

    @classmethod
    def from_table(cls, table: Mapping[str, object], where: str) -> FaultsParams:
        fields.known_keys(table, ("pillars",), where)
        items = table.get("pillars", [])
        if not isinstance(items, list | tuple):
            raise ConfigError(f"{where}.pillars", "must be a list of tables")
        specs = []
        for i, item in enumerate(items):
            field = f"{where}.pillars[{i}]"
            if not isinstance(item, dict):
                raise ConfigError(field, "must be a table {node_id, taxel, pillar, kind, from_s}")
            for required in ("node_id", "taxel"):
                if required not in item:
                    raise ConfigError(f"{field}.{required}", "missing")
            specs.append(build(FaultSpec, item, field))
        return cls(tuple(specs))


class Faults:
    def __init__(
        self, p: FaultsParams, node_ids: Sequence[int], pillars: int, constants: SensorConstants,
        *, adc: bool,
    ) -> None:
        full = constants.adc_full_scale_code * constants.resistance_lsb_ohm
        self.values = {"open": full if adc else np.inf, "short": 0.0, "saturated": full}
        index = {node: i for i, node in enumerate(node_ids)}
        self.items = [
            (index[f.node_id], f.taxel, PILLARS.index(f.pillar), f.kind, f.from_s)
            for f in p.pillars
        ]
        self.stuck: dict[int, float] = {}
        assert all(item[2] < pillars for item in self.items)

    def apply(self, r_ohm: F64, time_s: F64) -> F64:
        """In place on (n, patches, 9, P)."""
        for i, (patch, taxel, pillar, kind, from_s) in enumerate(self.items):
            on = np.flatnonzero(time_s >= from_s)
            if on.size == 0:
                continue
            channel = r_ohm[on, patch, taxel, pillar]
            if kind == "stuck":
                value = self.stuck.setdefault(i, float(channel[0]))
            else:
                value = self.values[kind]
            r_ohm[on, patch, taxel, pillar] = value
        return r_ohm
