"""Readouts: passive_matrix against an independent nodal analysis; zero_potential leakage."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from sim.effects.network import passive_matrix_resistance
from sim.effects.readout import zero_potential_resistance
from skin.constants import DEFAULT_CONSTANTS
from skin.tripod import resistance_from_force

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels

R0 = DEFAULT_CONSTANTS.nominal_resistance_ohm
WIRES = [f"{w}{i}" for w in "ABCD" for i in range(3)]


def pillar_wires(r: int, c: int) -> dict[str, tuple[str, str]]:
    """The wiring of docs/sim.md, written out by hand."""
    return {"z": (f"A{r}", f"C{c}"), "x": (f"A{r}", f"D{c}"), "y": (f"B{r}", f"C{c}")}


def nodal_resistance(r_ohm: np.ndarray, taxel: int, pillar: str) -> float:
    """Inject 1 A into the pillar's upper wire, ground its lower wire, solve KCL on 12 nodes."""
    g = np.zeros((12, 12))
    for k in range(9):
        for p, (a, b) in pillar_wires(*divmod(k, 3)).items():
            i, j = WIRES.index(a), WIRES.index(b)
            cond = 1.0 / r_ohm[k, "zxy".index(p)]
            g[i, i] += cond
            g[j, j] += cond
            g[i, j] -= cond
            g[j, i] -= cond
    source, sink = (WIRES.index(w) for w in pillar_wires(*divmod(taxel, 3))[pillar])
    keep = [n for n in range(12) if n != sink]
    current = np.zeros(12)
    current[source] = 1.0
    v = np.linalg.solve(g[np.ix_(keep, keep)], current[keep])
    return float(v[keep.index(source)])


def test_passive_matrix_matches_nodal_analysis() -> None:
    rng = np.random.default_rng(7)
    r = R0 * rng.uniform(0.8, 1.2, size=(9, 3))
    measured = passive_matrix_resistance(r[None])[0]
    for k in range(9):
        for p, pillar in enumerate("zxy"):
            assert measured[k, p] == pytest.approx(nodal_resistance(r, k, pillar), rel=1e-10)


@settings(max_examples=25, deadline=None)
@given(arrays(np.float64, (9, 3), elements=st.floats(200.0, 5000.0)))
def test_passive_matrix_never_exceeds_the_pillar(r: np.ndarray) -> None:
    measured = passive_matrix_resistance(r[None])[0]
    assert np.all(measured <= r * (1 + 1e-12))
    assert np.all(measured > 0)
    k, p = divmod(int(np.argmax(r)), 3)
    assert measured[k, p] == pytest.approx(nodal_resistance(r, k, "zxy"[p]), rel=1e-9)


def test_ghosting_grows_with_neighbour_load() -> None:
    readings = []
    for load in (0.0, 1.0, 2.0, 3.0, 4.0):
        force = np.zeros((9, 3))
        force[:, 2] = load
        force[4] = 0.0  # the centre taxel is untouched
        readings.append(passive_matrix_resistance(resistance_from_force(force)[None])[0, 4, 0])
    ghost = readings[0] - np.array(readings)
    assert ghost[0] == 0.0
    assert np.all(np.diff(ghost) > 0)
    assert ghost[-1] > 0.5  # ohm: visible to a 0.05 ohm ADC


def test_zero_potential_leakage_small_and_growing() -> None:
    leaks = []
    for load in (0.0, 2.0, 4.0):
        force = np.zeros((9, 3))
        force[:, 2] = load
        force[4] = 0.0
        r = resistance_from_force(force)
        measured = zero_potential_resistance(r[None], 1.0e4, float(R0[0]))[0]
        leaks.append(measured[4, 0] / r[4, 0] - 1.0)
    assert 0.0 < leaks[0] < 1e-3
    assert leaks[0] < leaks[1] < leaks[2] < 1e-3
    # at rest: column C1 carries three z (1 kΩ) and three y (√2 kΩ) pillars
    g_column = 3 / R0[0] + 3 / R0[2]
    assert leaks[0] == pytest.approx((1 + R0[0] * g_column) / 1.0e4)
