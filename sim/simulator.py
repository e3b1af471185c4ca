"""The simulator: a scene, stepped in batches of time steps."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sim.effects.faults import Faults, FaultsParams
from sim.effects.noise import Noise, NoiseParams
from sim.loads import Load, make_load
from sim.pipeline import Pipeline
from sim.rng import stream
from sim.scene import Scene
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.errors import ConfigError, StrainLimitError
from skin.tripod import displacement_from_force

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Frame:
    """n time steps: what the patches report and the true force that produced it."""

    time_s: F64  # (n,)
    resistance_ohm: F64  # (n, patches, 9, P); +inf = open circuit, 0 = short
    force_N: F64  # (n, patches, 9, 3) true (Fx, Fy, Fz), before crosstalk
    slip: NDArray[np.bool_]  # (n, patches) true: a load slides over the patch


class Simulator:
    """Steps a scene. Patches with no load (and no drift) are served from a cached baseline."""

    def __init__(
        self, scene: Scene, *, seed: int | None = None,
        constants: SensorConstants = DEFAULT_CONSTANTS,
    ) -> None:
        self.scene, self.constants = scene, constants
        self.seed = scene.seed if seed is None else seed
        self.node_ids = scene.node_ids
        self.pillars = scene.pillars
        self._k = 0
        index = {node: i for i, node in enumerate(self.node_ids)}
        self._loads: list[tuple[NDArray[np.intp], Load]] = []
        for i, spec in enumerate(scene.loads):
            if spec.kind == "idle":
                continue
            load = make_load(
                spec.kind, spec.params, len(spec.patches), rate_hz=scene.rate_hz,
                pitch_m=constants.taxel_pitch_m, seed=self.seed, name=f"loads[{i}]",
            )
            self._check_strain(i, load)
            self._loads.append((np.array([index[n] for n in spec.patches], dtype=np.intp), load))
        loaded = sorted({int(j) for idx, _ in self._loads for j in idx})
        every = "drift" in scene.effects
        self._active = np.arange(len(self.node_ids)) if every else np.array(loaded, dtype=np.intp)
        self._idle = np.setdiff1d(np.arange(len(self.node_ids)), self._active)
        self._pipeline = Pipeline(scene, constants, self.seed, self._active.size)
        self._baseline = self._pipeline.baseline()[:, : self.pillars]
        noise = scene.effects.get("noise")
        self._noise = (
            Noise(noise, constants, self.pillars, stream(self.seed, "noise"))
            if isinstance(noise, NoiseParams) else None
        )
        faults = scene.effects.get("faults")
        self._faults = (
            Faults(faults, self.node_ids, self.pillars, constants, adc=self._noise is not None)
            if isinstance(faults, FaultsParams) else None
        )

    def _check_strain(self, i: int, load: Load) -> None:
        """Fail before running if a load's largest force (after crosstalk) over-strains a
        pillar: naming the load's field, or the crosstalk's coupling when the force alone
        is fine and only the coupling's gain takes it past the limit."""
        gain = float(self.scene.crosstalk_matrix().sum(axis=1).max())
        for name, value, force in load.peak_forces():
            try:
                displacement_from_force(force * gain, self.constants)
            except StrainLimitError as err:
                field, shown = f"loads[{i}].{name}", f"{value:g}"
                if gain > 1.0 and _strains(force, self.constants) is None:
                    crosstalk = self.scene.effects["elastic_crosstalk"]
                    field = "effects.elastic_crosstalk.coupling"
                    shown = (f"{crosstalk.coupling:g} (with diagonal_coupling "
                             f"{crosstalk.diagonal_coupling:g}: x{gain:.3g} on loads[{i}])")
                raise ConfigError(
                    field,
                    f"{shown} strains a pillar past {100 * self.constants.max_strain:.0f} % "
                    f"(force ({', '.join(f'{f:.3g}' for f in force * gain)}) N on a taxel "
                    f"after crosstalk): {err}", source=self.scene.source or None,
                ) from err

    def run(self, n: int) -> Frame:
        """The next ``n`` time steps, 1/rate_hz apart."""
        if not isinstance(n, int | np.integer) or n < 0:
            raise ConfigError("n", f"must be a non-negative number of steps, got {n!r}")
        time_s = (self._k + np.arange(n)) / self.scene.rate_hz
        patches = len(self.node_ids)
        force = np.zeros((n, patches, 9, 3))
        slip = np.zeros((n, patches), dtype=bool)
        for idx, load in self._loads:
            force[:, idx] += load.forces(self._k, n)
            slip[:, idx] |= load.slipping(self._k, n)
        out = np.empty((n, patches, 9, self.pillars))
        if self._idle.size:
            out[:, self._idle] = self._baseline
        if self._active.size:
            active = force if self._idle.size == 0 else force[:, self._active]
            try:
                r = self._pipeline.resistance(active, time_s)
            except StrainLimitError as err:
                problem = f"the combined loads over-strain a pillar: {err}"
                raise ConfigError("loads", problem, source=self.scene.source or None) from err
            if self._idle.size == 0:
                out[...] = r[..., : self.pillars]
            else:
                out[:, self._active] = r[..., : self.pillars]
        if self._noise is not None:
            self._noise.apply(out)
        if self._faults is not None:
            self._faults.apply(out, time_s)
        self._k += n
        return Frame(time_s=time_s, resistance_ohm=out, force_N=force, slip=slip)

    def step(self) -> Frame:
        """One time step; the same as run(1)."""
        return self.run(1)


def _strains(force: F64, constants: SensorConstants) -> StrainLimitError | None:
    """The strain error ``force`` alone gives, or None."""
    try:
        displacement_from_force(force, constants)
    except StrainLimitError as err:
        return err
    return None
