"""Synthetic patch data for decoder tests: exact forward model, own crosstalk, noise.

Independent of sim/ on purpose (decoder tests must not need the simulator):
forces -> crosstalk F_eff = M F per component -> skin.tripod forward -> read noise
and 0.05-ohm quantisation.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np
import pytest
from numpy.typing import NDArray

from skin.constants import DEFAULT_CONSTANTS
from skin.tripod import resistance_from_force

F64 = NDArray[np.float64]
Synth = Callable[..., tuple[F64, F64]]


def crosstalk_matrix(strength: float) -> F64:
    """M = I + strength * (4-neighbour adjacency of the 3x3 grid)."""
    m = np.eye(9)
    for k in range(9):
        r, c = divmod(k, 3)
        for dr, dc in ((0, 1), (1, 0), (0, -1), (-1, 0)):
            rr, cc = r + dr, c + dc
            if 0 <= rr < 3 and 0 <= cc < 3:
                m[k, rr * 3 + cc] = strength
    return m


def make_data(n: int, *, pillars: int = 1, seed: int = 0, strength: float = 0.05,
              noise: bool = True, fz_max: float = 5.0, fz_min: float = 0.0,
              same: bool = False) -> tuple[F64, F64]:
    """(resistance (n, 9, P), force (n, 9, 3)) like the paper scene (P=1) or with shear (P=3).

    ``same``: every taxel of a sample carries the same Fz (a one-dimensional load pattern)."""
    rng = np.random.default_rng(seed)
    force = np.zeros((n, 9, 3))
    force[..., 2] = rng.uniform(fz_min, fz_max, (n, 1) if same else (n, 9))
    if pillars == 3:
        force[..., :2] = rng.uniform(-1.0, 1.0, (n, 9, 2))
    return read_forces(force, pillars=pillars, seed=seed, strength=strength, noise=noise)


def read_forces(force: F64, *, pillars: int = 1, seed: int = 0, strength: float = 0.05,
                noise: bool = True) -> tuple[F64, F64]:
    """What a patch reads under ``force`` (n, 9, 3): crosstalk, the exact model, noise."""
    rng = np.random.default_rng(seed + 1000)
    effective = np.einsum("kj,njc->nkc", crosstalk_matrix(strength), force)
    if pillars == 1:
        effective[..., :2] = 0.0
    r = resistance_from_force(effective)[..., :pillars]
    if noise:
        r0 = DEFAULT_CONSTANTS.nominal_resistance_ohm[:pillars]
        r = r + rng.normal(0.0, 5e-4, r.shape) * r0
        lsb = DEFAULT_CONSTANTS.resistance_lsb_ohm
        r = np.round(r / lsb) * lsb
    return r, force


@pytest.fixture(scope="session", autouse=True)
def one_blas_thread() -> Iterator[None]:
    """As `skin train` and `skin bench` run LM: BLAS on one thread (SciPy imported first, so
    its own OpenBLAS is limited too). On a busy 2-core machine two BLAS threads per process
    make each LM epoch up to 10x slower."""
    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1, user_api="blas"):
        yield


@pytest.fixture(scope="session")
def synth() -> Synth:
    return make_data


@pytest.fixture(scope="session")
def paper_data() -> tuple[F64, F64, F64, F64]:
    """1000 training and 100 test samples, z-only, crosstalk 0.05, noise."""
    r, f = make_data(1100, seed=1)
    return r[:1000], f[:1000], r[1000:], f[1000:]


@pytest.fixture(scope="session")
def xyz_data() -> tuple[F64, F64, F64, F64]:
    r, f = make_data(700, pillars=3, seed=2)
    return r[:600], f[:600], r[600:], f[600:]
