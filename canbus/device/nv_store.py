"""A simulated device's non-volatile memory: one JSON file per device, written atomically.

What 0x1010 ("save") and LSS "store configuration" keep across a power cycle: object values
by area (communication 0x1000..0x1FFF, manufacturer 0x2000..0x5FFF, application
0x6000..0x9FFF) and the LSS node-ID and bit timing. The file names the device it belongs to
(vendor, product, revision, serial of 0x1018): a file of another device is refused, as a
corrupt one is, with one line naming the file and the field (:class:`NvStoreError`), never
ignored. Every write is a temp file, fsync and rename (``skin.atomic``): a power cut leaves
the old file or the new one, never half of one.

```json
{"format": "canskin-nv-store", "version": 1,
 "identity": {"vendor": 0, "product": 1, "revision": 65536, "serial": 4097},
 "lss": {"node_id": 5, "bit_timing": 0},
 "objects": {"1017:00": "6400", "2002:01": "c8b70f00"}}
```
"""

from __future__ import annotations

import json
import os
import re
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from canbus.identity import Identity
from skin.atomic import atomic_write
from skin.errors import ConfigError
from skin.inputs import fields

FORMAT, VERSION = "canskin-nv-store", 1
MAX_BYTES = 1 << 20
"""A store holds at most a few hundred objects; a larger file is not one."""
AREAS = {"communication": (0x1000, 0x1FFF), "manufacturer": (0x2000, 0x5FFF),
         "application": (0x6000, 0x9FFF)}
BIT_TIMINGS = range(0, 10)
"""CiA 305 table 0: 0 = 1000, 1 = 800, 2 = 500, 3 = 250, 4 = 125, 6 = 50, 7 = 20, 8 = 10
kbit/s, 9 = automatic (5 is reserved)."""
_KEY = re.compile(r"^([0-9A-F]{4}):([0-9A-F]{2})$")


class NvStoreError(ConfigError):
    """A state file that is not this device's store: corrupt, foreign or of another format."""


@dataclass
class NvContent:
    """What a store holds."""

    objects: dict[tuple[int, int], bytes] = field(default_factory=dict)
    node_id: int | None = None
    bit_timing: int | None = None


class NvStore:
    """The non-volatile memory of the device ``identity``, kept in ``path`` (None: in memory
    only, for the life of the process: it survives NMT resets, not a restart)."""

    def __init__(self, path: str | os.PathLike[str] | None, identity: Identity) -> None:
        self.path = None if path is None else Path(path)
        self.identity = identity
        self._lock = threading.Lock()
        self.content = self._load()

    @classmethod
    def in_dir(cls, folder: str | os.PathLike[str], kind: str, identity: Identity) -> NvStore:
        """The store of a device in ``folder``: ``<kind>-<serial as 8 hex digits>.json``."""
        return cls(Path(folder) / f"{kind}-{identity.serial:08x}.json", identity)

    def save_objects(self, values: dict[tuple[int, int], bytes], first: int, last: int) -> None:
        """Keep ``values`` as the area ``first..last`` (what was stored there before goes)."""
        with self._lock:
            kept = {k: v for k, v in self.content.objects.items() if not first <= k[0] <= last}
            kept.update({k: v for k, v in values.items() if first <= k[0] <= last})
            self.content.objects = kept
            self._write()

    def forget_objects(self, first: int, last: int) -> None:
        """"load": the area's defaults come back at the next reset."""
        with self._lock:
            self.content.objects = {k: v for k, v in self.content.objects.items()
                                    if not first <= k[0] <= last}
            self._write()

    def save_lss(self, node_id: int, bit_timing: int | None) -> None:
        with self._lock:
            self.content.node_id = node_id
            self.content.bit_timing = bit_timing
            self._write()

    def _write(self) -> None:
        if self.path is None:
            return
        doc: dict[str, Any] = {"format": FORMAT, "version": VERSION,
                               "identity": self.identity.as_dict()}
        if self.content.node_id is not None:
            doc["lss"] = {"node_id": self.content.node_id,
                          "bit_timing": self.content.bit_timing}
        doc["objects"] = {f"{i:04X}:{s:02X}": raw.hex()
                          for (i, s), raw in sorted(self.content.objects.items())}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_write(self.path) as handle:
            handle.write(json.dumps(doc, indent=1).encode() + b"\n")

    # --- reading ------------------------------------------------------------------------

    def _fail(self, where: str, problem: str) -> NvStoreError:
        return NvStoreError(f"{self.path or 'store'}{'.' + where if where else ''}", problem)

    def _load(self) -> NvContent:
        if self.path is None or not self.path.exists():
            return NvContent()
        if not self.path.is_file():
            raise self._fail("", "not a regular file")
        try:
            size = self.path.stat().st_size
            if size > MAX_BYTES:
                raise self._fail("", f"{size} bytes: too large for a device's store")
            doc = json.loads(self.path.read_bytes().decode("utf-8"))
        except (OSError, UnicodeDecodeError, ValueError) as err:
            if isinstance(err, NvStoreError):
                raise
            raise self._fail("", f"not a readable state file ({err})") from err
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise self._fail("format", f"not a canskin non-volatile store (want {FORMAT!r})")
        if doc.get("version") != VERSION:
            raise self._fail("version", f"{doc.get('version')!r} is not a version this "
                                        f"canskin reads ({VERSION})")
        self._check_identity(doc.get("identity"))
        content = NvContent(objects=self._objects(doc.get("objects", {})))
        if "lss" in doc:
            content.node_id, content.bit_timing = self._lss(doc["lss"])
        return content

    def _check_identity(self, found: Any) -> None:
        if not isinstance(found, dict):
            raise self._fail("identity", "missing or not a table")
        for name in self.identity.as_dict():
            value = found.get(name)
            if not isinstance(value, int) or isinstance(value, bool):
                raise self._fail(f"identity.{name}", f"{value!r} is not an integer")
            if value != getattr(self.identity, name):
                raise self._fail(f"identity.{name}", f"0x{value:08X}: the store of another "
                                 f"device (this one has 0x{getattr(self.identity, name):08X})")

    def _objects(self, found: Any) -> dict[tuple[int, int], bytes]:
        if not isinstance(found, dict):
            raise self._fail("objects", "not a table")
        out = {}
        for key, value in found.items():
            m = _KEY.match(key) if isinstance(key, str) else None
            if m is None:
                raise self._fail(f"objects.{key}", "not an object key (IIII:SS in hex)")
            try:
                raw = bytes.fromhex(value) if isinstance(value, str) else None
            except ValueError:
                raw = None
            if raw is None or not 0 < len(raw) <= 8:
                raise self._fail(f"objects.{key}", f"{value!r} is not 1..8 bytes in hex")
            out[(int(m.group(1), 16), int(m.group(2), 16))] = raw
        return out

    def _lss(self, found: Any) -> tuple[int, int | None]:
        if not isinstance(found, dict):
            raise self._fail("lss", "not a table")
        node_id, bit_timing = found.get("node_id"), found.get("bit_timing")
        try:
            node_id = fields.node_id(node_id, "lss.node_id", unconfigured=True)
        except ConfigError as err:
            raise self._fail("lss.node_id", err.problem) from err
        if bit_timing is not None and (not isinstance(bit_timing, int) or
                                       isinstance(bit_timing, bool) or
                                       bit_timing not in BIT_TIMINGS or bit_timing == 5):
            raise self._fail("lss.bit_timing", f"{bit_timing!r} is not a CiA 305 bit timing")
        return node_id, bit_timing
