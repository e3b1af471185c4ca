"""The arithmetic of the contact summary (:mod:`skin.contact`): the sums over the taxels in
contact, the centre of pressure and the tangential ratio of ``n`` samples at once
(:class:`SumsKernel`), and what the API reads of them (:class:`ContactInstant`).

The kernel works in buffers made once for its ``n`` rows (the host keeps one per batch
composition): the host summarises every publishing batch, a dozen patches a hundred times
a second, and there numpy's cost per call, not the arithmetic, sets the price, lowest for a
call that allocates nothing and broadcasts nothing. One matrix product gives every sum.

Every sample's figures are the same bits in any batch, alone or among others: the weights
of that product are a strided view, which makes numpy sum each output over the taxels in
order, instead of BLAS, whose kernels sum in an order that depends on the number of rows.

Layout of :attr:`ContactInstant.sums`, ``(6, n, 3)``: six blocks of ``n`` rows (net Fx,
Fy, Fz, the taxels in contact, the valid taxels, the tangential ratio), each row the plain
sum (column 0) and the sums weighted by each taxel's x and y in pitches (columns 1, 2),
except in the Fz block, whose columns 1 and 2 hold the centre of pressure (m) computed
from them.
"""

from __future__ import annotations

import functools

import numpy as np
from numpy.typing import NDArray

from skin.constants import TAXELS_PER_PATCH

F64 = NDArray[np.float64]
Bools = NDArray[np.bool_]

T = TAXELS_PER_PATCH
_ROW, _COL = np.divmod(np.arange(T), 3)
UNIT_XY: F64 = np.stack([_COL - 1.0, _ROW - 1.0], axis=1)
"""(9, 2) taxel centres in pitches, patch frame."""
SMALLEST_N = 5e-324
"""The smallest positive float64: a normal force at or above it is a normal force."""

FX, FY, FZ, COUNT, VALID, RATIO = range(6)
"""The blocks of :attr:`ContactInstant.sums` (row 0: the plain sums and the ratio)."""
BLOCKS = 6


def _strided(weights: F64) -> F64:
    """``weights`` as a view with no contiguous dimension (numpy's own matmul loop)."""
    room = np.zeros((2 * weights.shape[0], 2 * weights.shape[1]))
    room[::2, ::2] = weights
    out: F64 = room[::2, ::2]
    return out


_WEIGHTS = _strided(np.stack([np.ones(T), UNIT_XY[:, 0], UNIT_XY[:, 1]], axis=1))
"""(9, 3): a sum, an x-weighted and a y-weighted sum over the taxels."""
_MOMENT_WEIGHTS = _strided(UNIT_XY)
"""(9, 2): the x- and y-weighted sums alone (the same products, in the same order)."""


class RowParams:
    """Each row's geometry and thresholds as arrays (``(n,)``; the position ``(2,)`` or
    ``(n, 2)``, the rotation ``(2, 2)`` or ``(n, 2, 2)``)."""

    def __init__(self, threshold: F64, pitch: F64, friction: F64, near_slip_ratio: F64,
                 position: F64, rotation: F64) -> None:
        self.threshold = threshold  # taxel_contact_N
        self.pitch = pitch  # m
        self.friction = friction  # μ
        self.near_slip_ratio = near_slip_ratio  # (1 - margin)·μ
        self.position = position  # m
        self.rotation = rotation

    @functools.cached_property
    def taxel_threshold(self) -> F64:
        """(n·9,) each taxel's contact threshold."""
        out: F64 = np.repeat(self.threshold, T)
        return out


class SumsKernel:
    """Summarises batches of ``n`` rows with ``rows``'s parameters into its own buffers.

    :meth:`run` fills :attr:`sums` (overwritten by the next run); :meth:`instant` copies
    them into a :class:`ContactInstant`. ``checked`` runs take forces that may be nonzero
    where not valid; unchecked runs take a decoder's forces as the host has them (finite,
    0 where not valid, every threshold positive) and skip that mask.
    """

    def __init__(self, rows: RowParams) -> None:
        n = self.n = len(rows.threshold)
        self.rows = rows
        taxels = np.zeros((BLOCKS, n * T))  # Fx, Fy, Fz of the taxels in contact, contact,
        self._contact = taxels[COUNT]  # valid, and a row of zeros (the ratio's block)
        self._masked = taxels[:COUNT]
        self._valid = taxels[VALID].reshape(n, T)
        self._taxels = taxels.reshape(BLOCKS * n, T)
        self._sums: F64 = np.empty((BLOCKS * n, 3))
        self.sums = self._sums.reshape(BLOCKS, n, 3)
        """The sums of the last run (the module docstring)."""
        self._fx, self._fy, self._fz = (self.sums[b, :, 0] for b in (FX, FY, FZ))
        self._cop, self._ratio = self.sums[FZ, :, 1:].T, self.sums[RATIO, :, 0]
        self.tested = self.sums[FZ:, None, :, 0]
        """(4, 1, n) net Fz, taxels in contact, valid taxels, ratio: what the state tests."""
        self.published = self.sums[FZ, :, ::-1].T
        """(3, n) CoP y, CoP x (m), net Fz (N): the scaled figures of the default PDO."""
        self._denominator = np.empty(n)
        self._smallest = np.full(n, SMALLEST_N)
        self._shear = np.empty(n)

    def run(self, force: F64, valid: Bools, *, checked: bool = False) -> None:
        """Summarise ``(n, 9, 3)`` forces, ``(n, 9)`` valid into :attr:`sums`."""
        flat = force.reshape(self.n * T, 3)
        contact = self._contact
        np.greater(flat[:, 2], self.rows.taxel_threshold, out=contact)
        if checked:
            np.multiply(contact, valid.reshape(-1), out=contact)
        np.multiply(flat.T, contact, out=self._masked)
        np.copyto(self._valid, valid)
        np.matmul(self._taxels, _WEIGHTS, out=self._sums)
        # 0 where no taxel is in contact: 0 / the smallest subnormal is 0; divided first,
        # so a vanishing normal force gives a bounded CoP, never 0·inf
        denominator = np.maximum(self._fz, self._smallest, out=self._denominator)
        np.hypot(self._fx, self._fy, out=self._shear)
        np.divide(self._shear, denominator, out=self._ratio)
        cop = self._cop
        np.divide(cop, denominator, out=cop)
        np.multiply(cop, self.rows.pitch, out=cop)

    def instant(self, force: F64, valid: Bools, *, bounded: bool,
                checked: bool = False) -> ContactInstant:
        """:meth:`run`, then the summary as the API gives it (a copy of the sums)."""
        self.run(force, valid, checked=checked)
        return ContactInstant(self.sums.copy(), force, valid, self.rows, bounded=bounded,
                              checked=checked)


class ContactInstant:
    """What ``n`` samples say on their own (no history): see :mod:`skin.contact`.

    The sums (:attr:`sums`, the module docstring) are computed at once; the rest (torque,
    placed frame, the taxels in contact and their slip tests) when first read, from the
    forces and validity it was given.
    """

    def __init__(self, sums: F64, force: F64, valid: Bools, rows: RowParams, *,
                 bounded: bool = False, checked: bool = False) -> None:
        self.sums = sums
        self.bounded = bounded
        """Every figure is far inside float64's range (a decoder's forces)."""
        self.rows = rows
        self._force = force  # (n, 9, 3)
        self._valid = valid  # (n, 9)
        self._checked = checked  # forces may be nonzero where not valid

    def _block(self, block: int, column: int = 0) -> F64:
        out: F64 = self.sums[block, :, column]
        return out

    def __len__(self) -> int:
        return int(self.sums.shape[1])

    @property
    def friction(self) -> F64:
        """(n,) μ of each row."""
        return self.rows.friction

    @property
    def near_slip_ratio(self) -> F64:
        """(n,) (1 - margin)·μ of each row."""
        return self.rows.near_slip_ratio

    @functools.cached_property
    def force_N(self) -> F64:
        """(n, 3) the net force over the taxels in contact."""
        out: F64 = self.sums[:FZ + 1, :, 0].T
        return out

    @property
    def cop_m(self) -> F64:
        """(n, 2) the centre of pressure, patch frame; 0 where not defined."""
        out: F64 = self.sums[FZ, :, 1:]
        return out

    @property
    def tangential_ratio(self) -> F64:
        """(n,) |(Fx, Fy)| / Fz of the net force; 0 where the CoP is not defined (+inf for
        shear over a vanishing normal force, possible only with ``taxel_contact_N`` = 0)."""
        return self._block(RATIO)

    @property
    def taxel_count(self) -> F64:
        """(n,) :attr:`taxels_in_contact` as the float64 sum it is counted by (exact)."""
        return self._block(COUNT)

    @functools.cached_property
    def taxels_in_contact(self) -> NDArray[np.int64]:
        """(n,)"""
        out: NDArray[np.int64] = self._block(COUNT).astype(np.int64)
        return out

    @functools.cached_property
    def valid_taxels(self) -> NDArray[np.int64]:
        """(n,) the taxels the summary rests on."""
        out: NDArray[np.int64] = self._block(VALID).astype(np.int64)
        return out

    @functools.cached_property
    def known(self) -> Bools:
        """(n,) a valid taxel: the sample says something."""
        out: Bools = self._block(VALID) > 0
        return out

    @functools.cached_property
    def cop_defined(self) -> Bools:
        """(n,) a taxel is in contact: a taxel in contact has Fz > taxel_contact_N >= 0,
        so their sum is > 0 exactly then."""
        out: Bools = self._block(FZ) > 0
        return out

    @functools.cached_property
    def contact_taxels(self) -> Bools:
        """(n, 9) the valid taxels in contact (normal force above the threshold)."""
        out: Bools = self._force[:, :, 2] > self.rows.threshold[:, None]
        if self._checked:
            out &= self._valid
        return out

    @functools.cached_property
    def _on(self) -> F64:
        """(n, 9, 3) the forces of the taxels in contact, 0 elsewhere."""
        out: F64 = self._force * self.contact_taxels[:, :, None]
        return out

    @functools.cached_property
    def contact_area_m2(self) -> F64:
        """(n,) the taxels in contact times a taxel's share of the patch (pitch²)."""
        out: F64 = self.taxels_in_contact * self.rows.pitch ** 2
        return out

    @functools.cached_property
    def near_slip(self) -> Bools:
        """(n,) the net force within the margin of the friction cone, or beyond it."""
        out: Bools = self.cop_defined & (self.tangential_ratio >= self.near_slip_ratio)
        return out

    @functools.cached_property
    def slip(self) -> Bools:
        """(n,) the net force on or beyond the friction cone (the cone alone: the host's
        slip state adds hysteresis, :mod:`skin.contact_state`)."""
        out: Bools = self.cop_defined & (self.tangential_ratio >= self.friction)
        return out

    @functools.cached_property
    def torque_Nm(self) -> F64:
        """(n, 3) about the patch centre, on the surface, patch frame: τx = Σ y·Fz,
        τy = −Σ x·Fz, τz = Σ (x·Fy − y·Fx)."""
        moments = np.matmul(np.ascontiguousarray(self._on[:, :, 2]), _MOMENT_WEIGHTS)
        with np.errstate(over="ignore", invalid="ignore"):
            twist = self._block(FY, 1) - self._block(FX, 2)  # Σ x·Fy − Σ y·Fx
            out: F64 = np.stack([moments[:, 1], -moments[:, 0], twist], axis=1) \
                * self.rows.pitch[:, None]
        return out

    @functools.cached_property
    def cop_placed_m(self) -> F64:
        """(n, 2) the CoP in the placed frame (the patch's position where not defined)."""
        with np.errstate(over="ignore", invalid="ignore"):
            return _turn(self.rows.rotation, self.cop_m) + self.rows.position

    @functools.cached_property
    def force_placed_N(self) -> F64:
        """(n, 3) the net force with (Fx, Fy) turned into the placed frame."""
        out = self.force_N.copy()
        with np.errstate(over="ignore", invalid="ignore"):
            out[:, :2] = _turn(self.rows.rotation, self.force_N[:, :2])
        return out

    @functools.cached_property
    def taxel_shear_N(self) -> F64:
        with np.errstate(over="ignore"):
            out: F64 = np.hypot(self._on[:, :, 0], self._on[:, :, 1])
        return out

    @functools.cached_property
    def taxel_near_slip(self) -> Bools:
        """(n, 9) taxels in contact within the margin of their own friction cone."""
        with np.errstate(over="ignore"):
            out: Bools = self.contact_taxels & (
                self.taxel_shear_N >= self.near_slip_ratio[:, None] * self._on[:, :, 2])
        return out

    @functools.cached_property
    def taxel_slip(self) -> Bools:
        """(n, 9) taxels in contact at or beyond their own friction cone."""
        with np.errstate(over="ignore"):
            out: Bools = self.contact_taxels & (
                self.taxel_shear_N >= self.friction[:, None] * self._on[:, :, 2])
        return out


def _turn(rotation: F64, vectors: F64) -> F64:
    """``(n, 2)`` vectors turned by ``(2, 2)`` or ``(n, 2, 2)`` rotations, elementwise (the
    same bits for a row whatever the others, unlike a matrix product)."""
    r = rotation if rotation.ndim == 3 else rotation[None]
    x, y = vectors[:, 0], vectors[:, 1]
    out = np.empty_like(vectors)
    out[:, 0] = r[:, 0, 0] * x + r[:, 0, 1] * y
    out[:, 1] = r[:, 1, 0] * x + r[:, 1, 1] * y
    return out
