"""The force sample's two candidate encodings, measured side by side on the same frame.

* **binary**: the documented layout of :mod:`canbus.zenoh.schema` (``struct`` head,
  the forces as little-endian float64, reasons, valid bits, names);
* **msgpack**: the same fields as a msgpack map with the forces as a list of 27 floats
  and the reasons as a list of ints: what a reader in any language decodes with a
  msgpack library and no layout;
* **msgpack-bin**: the same map with forces and reasons as byte strings (the layout
  of the arrays is then documented anyway).

Each is timed encoding and decoding back to a ``ForceFrame`` with the same checks (forces
finite, valid bits agreeing with the reasons), best of ``repeats`` runs of ``n`` each, and
its size given.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from functools import partial
from typing import Any

import msgpack
import numpy as np

from canbus.master.dataplane import ForceFrame
from canbus.zenoh import schema


def sample_frame() -> ForceFrame:
    """A typical complete sample: 3-axis forces of a press, every taxel valid."""
    rng = np.random.default_rng(1)
    force = rng.normal(0.0, 0.3, (9, 3))
    force[:, 2] = rng.uniform(0.0, 4.0, 9)
    return ForceFrame(3, 67, 123456, 17, time.time(), force, np.ones(9, bool),
                      np.zeros(9, np.uint8), True, True)


def _msgpack_fields(frame: ForceFrame, arrays_as_bytes: bool) -> dict[str, Any]:
    force: Any = frame.force_N.astype("<f8").tobytes() if arrays_as_bytes \
        else frame.force_N.reshape(-1).tolist()
    reason: Any = frame.reason.tobytes() if arrays_as_bytes else frame.reason.tolist()
    return {"v": 1, "host": "host0", "bus": "bus0", "patch": frame.patch,
            "force_node": frame.force_node, "cycle": frame.cycle,
            "sync_counter": frame.sync_counter, "t_sync": frame.timestamp,
            "t_published": 0.0, "t_sent": 0.0, "complete": frame.complete,
            "published": frame.published, "valid": int(np.dot(frame.valid, 1 << np.arange(9))),
            "reason": reason, "force_N": force}


def _msgpack_decode(payload: bytes, arrays_as_bytes: bool) -> ForceFrame:
    m = msgpack.unpackb(payload, raw=False)
    if arrays_as_bytes:
        force = np.frombuffer(m["force_N"], "<f8").reshape(9, 3).astype(np.float64)
        reason = np.frombuffer(m["reason"], np.uint8).copy()
    else:
        force = np.array(m["force_N"], dtype=np.float64).reshape(9, 3)
        reason = np.array(m["reason"], dtype=np.uint8)
    valid = (m["valid"] >> np.arange(9) & 1).astype(bool)
    # the checks the binary decoder makes, so that the times compare like with like
    if not np.array_equal(valid, reason == 0) or not np.isfinite(force).all():
        raise ValueError("inconsistent sample")
    return ForceFrame(m["patch"], m["force_node"], m["cycle"], m["sync_counter"], m["t_sync"],
                      force, valid, reason, m["complete"], m["published"])


def _best_us(call: Callable[[], object], n: int, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(n):
            call()
        best = min(best, time.perf_counter() - start)
    return 1e6 * best / n


def measure_codecs(n: int = 2000, repeats: int = 5) -> dict[str, dict[str, float]]:
    """{codec: {encode_us, decode_us, bytes}} on one typical sample; decoding checked."""
    frame = sample_frame()
    host, bus = b"host0", b"bus0"
    binary = schema.encode_forces(frame, host, bus, 0.0, 0.0)
    candidates: dict[str, tuple[Callable[[], bytes], Callable[[bytes], ForceFrame]]] = {
        "binary": (lambda: schema.encode_forces(frame, host, bus, 0.0, 0.0),
                   lambda p: schema.decode_forces(p).frame),
        "msgpack": (lambda: msgpack.packb(_msgpack_fields(frame, False)),
                    lambda p: _msgpack_decode(p, False)),
        "msgpack-bin": (lambda: msgpack.packb(_msgpack_fields(frame, True)),
                        lambda p: _msgpack_decode(p, True)),
    }
    out = {}
    for name, (encode, decode) in candidates.items():
        payload = encode()
        back = decode(payload)
        assert np.array_equal(back.force_N, frame.force_N) and back.cycle == frame.cycle
        out[name] = {"encode_us": _best_us(encode, n, repeats),
                     "decode_us": _best_us(partial(decode, payload), n, repeats),
                     "bytes": float(len(payload))}
    assert out["binary"]["bytes"] == len(binary)
    return out
