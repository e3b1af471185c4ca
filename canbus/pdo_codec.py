"""Vectorised PDO codec: numpy arrays <-> PDO payloads, driven by the mapping objects.

The mapping is read through a ``read(index, subindex) -> int`` function, so the same
code serves a device (its current object values), a master (values read by SDO) and an
EDS (its default values, :func:`read_defaults`). ``pack`` turns ``(n, V)`` values into
``(n, P, W)`` payload bytes in one gather; ``unpack`` is the inverse scatter. ``W``, the
codec's :attr:`~PdoCodec.width`, is 8 for classic PDOs and the longest PDO's length when
one is longer (a CAN FD PDO of up to 64 bytes, CiA 1301); shorter PDOs are zero-padded.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import canopen
import numpy as np
from numpy.typing import ArrayLike, NDArray

from skin.errors import ConfigError

TPDO_COMM = 0x1800
TPDO_MAP = 0x1A00
COB_ID_INVALID = 0x8000_0000

_DTYPES = {
    0x0001: "u1", 0x0002: "i1", 0x0003: "<i2", 0x0004: "<i4", 0x0005: "u1", 0x0006: "<u2",
    0x0007: "<u4", 0x0008: "<f4", 0x0011: "<f8", 0x0015: "<i8", 0x001B: "<u8",
}

Reader = Callable[[int, int], int]


@dataclass(frozen=True)
class MappedEntry:
    """One mapping entry: object ``index:subindex`` of ``bits`` bits."""

    index: int
    subindex: int
    bits: int

    @classmethod
    def from_raw(cls, raw: int) -> MappedEntry:
        return cls(raw >> 16, (raw >> 8) & 0xFF, raw & 0xFF)

    def to_raw(self) -> int:
        return (self.index << 16) | (self.subindex << 8) | self.bits


@dataclass(frozen=True)
class TpdoLayout:
    """A valid TPDO: 1-based number, CAN identifier and its mapped entries in order."""

    number: int
    cob_id: int
    entries: tuple[MappedEntry, ...]

    @property
    def size(self) -> int:
        return sum(e.bits for e in self.entries) // 8


def read_defaults(od: canopen.ObjectDictionary) -> Reader:
    """A reader of the object dictionary's default (EDS) values."""

    def read(index: int, subindex: int) -> int:
        obj = od[index]
        var = obj if isinstance(obj, canopen.objectdictionary.ODVariable) else obj[subindex]
        value = var.value if var.value is not None else var.default
        if value is None:
            raise ConfigError("eds", f"0x{index:04X}:{subindex:02X} has no value")
        return int(value)

    return read


def read_layouts(read: Reader, count: int, *, comm: int = TPDO_COMM,
                 mapping: int = TPDO_MAP) -> list[TpdoLayout]:
    """The valid PDOs among the first ``count`` (COB-ID bit 31 clear, entries mapped)."""
    layouts = []
    for n in range(count):
        cob_id = read(comm + n, 1)
        mapped = read(mapping + n, 0)
        if cob_id & COB_ID_INVALID or mapped == 0:
            continue
        entries = tuple(MappedEntry.from_raw(read(mapping + n, s)) for s in range(1, mapped + 1))
        layouts.append(TpdoLayout(n + 1, cob_id & 0x1FFF_FFFF, entries))
    return layouts


class PdoCodec:
    """Pack and unpack the mapped variables of several PDOs, batched over samples."""

    def __init__(self, layouts: Sequence[TpdoLayout], od: canopen.ObjectDictionary) -> None:
        self.layouts = tuple(layouts)
        variables: dict[tuple[int, int], np.dtype[np.generic]] = {}
        for layout in self.layouts:
            for entry in layout.entries:
                variables.setdefault((entry.index, entry.subindex), entry_dtype(entry, od))
        self.variables = tuple(variables)
        self.dtypes = tuple(variables.values())  # of each variable, in ``variables`` order
        self.cob_ids = np.array([layout.cob_id for layout in self.layouts], dtype=np.uint32)
        self.sizes = np.array([layout.size for layout in self.layouts], dtype=np.intp)
        self.width = max([8, *self.sizes.tolist()])
        """Bytes per PDO in :meth:`pack`'s and :meth:`unpack`'s arrays."""
        offsets, total = {}, 0
        self._groups: list[tuple[np.dtype[np.generic], NDArray[np.intp], NDArray[np.intp]]] = []
        by_dtype: dict[np.dtype[np.generic], list[int]] = {}
        for column, key in enumerate(self.variables):
            by_dtype.setdefault(variables[key], []).append(column)
        for dtype, columns in by_dtype.items():
            start = total
            for column in columns:
                offsets[self.variables[column]] = total
                total += dtype.itemsize
            self._groups.append((dtype, np.array(columns, dtype=np.intp),
                                 np.arange(start, total, dtype=np.intp)))
        self._row_bytes = total
        gather = np.full((len(self.layouts), self.width), total, dtype=np.intp)  # total: zero
        for p, layout in enumerate(self.layouts):
            at = 0
            for entry in layout.entries:
                width = entry.bits // 8
                base = offsets[(entry.index, entry.subindex)]
                gather[p, at:at + width] = np.arange(base, base + width)
                at += width
        self._gather = gather

    def column(self, index: int, subindex: int) -> int:
        """The column of variable ``index:subindex`` in the values array."""
        return self.variables.index((index, subindex))

    def pack(self, values: ArrayLike) -> NDArray[np.uint8]:
        """``(n, V)`` values (already in the objects' units) -> ``(n, P, W)`` payloads."""
        array = np.asarray(values)
        if array.ndim != 2 or array.shape[1] != len(self.variables):
            raise ValueError(f"expected (n, {len(self.variables)}) values, got {array.shape}")
        row = np.zeros((array.shape[0], self._row_bytes + 1), dtype=np.uint8)
        for dtype, columns, byte_columns in self._groups:
            block = np.ascontiguousarray(array[:, columns].astype(dtype))
            row[:, byte_columns] = block.view(np.uint8)
        return row[:, self._gather]

    def unpack(self, payloads: ArrayLike) -> NDArray[np.float64]:
        """``(n, P, W)`` payload bytes -> ``(n, V)`` values as float64."""
        data = np.asarray(payloads, dtype=np.uint8)
        if data.ndim != 3 or data.shape[1:] != self._gather.shape:
            raise ValueError(f"expected (n, {len(self.layouts)}, {self.width}) payloads, got "
                             f"{data.shape}")
        row = np.zeros((data.shape[0], self._row_bytes + 1), dtype=np.uint8)
        row[:, self._gather] = data
        out = np.empty((data.shape[0], len(self.variables)), dtype=np.float64)
        for dtype, columns, byte_columns in self._groups:
            out[:, columns] = np.ascontiguousarray(row[:, byte_columns]).view(dtype)
        return out


def entry_dtype(entry: MappedEntry, od: canopen.ObjectDictionary) -> np.dtype[np.generic]:
    where = f"0x{entry.index:04X}:{entry.subindex:02X}"
    try:
        obj = od[entry.index]
        var = obj if isinstance(obj, canopen.objectdictionary.ODVariable) else obj[entry.subindex]
    except KeyError as err:
        raise ConfigError("pdo mapping", f"{where} is not in the object dictionary") from err
    if var.data_type not in _DTYPES:
        raise ConfigError("pdo mapping", f"{where} has a type the codec cannot map")
    dtype = np.dtype(_DTYPES[var.data_type])
    if entry.bits != 8 * dtype.itemsize:
        raise ConfigError("pdo mapping", f"{where} is mapped with {entry.bits} bits, "
                          f"its type has {8 * dtype.itemsize}")
    return dtype
