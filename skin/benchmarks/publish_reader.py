"""The reader process of ``skin bench publish``: one Zenoh session connected to every
host, one :func:`~canbus.zenoh.reader.subscribe` to the whole skin, every sample noted.

Driven over a pipe (msgpack): ``ready`` once every host has been heard, ``measure`` and
``stop`` mark its CPU window; then it answers with what it received, as columns.
"""

from __future__ import annotations

import gc
import time
from multiprocessing.connection import Connection
from typing import Any

from skin.benchmarks.publish_host import receive, send

HEARD_TIMEOUT_S = 30.0


def reader_main(conn: Connection, endpoints: list[str], hosts: int) -> None:
    from canbus.master.zenoh_settings import ZenohSettings
    from canbus.zenoh.reader import subscribe
    from canbus.zenoh.schema import Sample

    columns: dict[str, list[Any]] = {k: [] for k in (
        "host", "patch", "cycle", "complete", "sync", "published", "sent", "received")}
    host_ids: dict[str, int] = {}
    append = [columns[k].append for k in columns]

    def note(sample: Sample) -> None:
        frame = sample.frame
        who = host_ids.setdefault(sample.host, len(host_ids))
        for put, value in zip(append, (who, frame.patch, frame.cycle, frame.complete,
                                       frame.timestamp, sample.published, sample.sent,
                                       sample.received), strict=True):
            put(value)

    settings = ZenohSettings(connect=tuple(endpoints))
    gc.collect()
    gc.freeze()
    with subscribe(settings=settings, ring=1, on_sample=note) as sub:
        deadline = time.monotonic() + HEARD_TIMEOUT_S
        while len(host_ids) < hosts and time.monotonic() < deadline:
            time.sleep(0.05)
        send(conn, {"ready": len(host_ids) >= hosts, "heard": sorted(host_ids)})
        receive(conn)  # measure
        cpu0, wall0 = time.process_time(), time.monotonic()
        receive(conn)  # stop
        cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
        counters = sub.counters()
    names = {v: k for k, v in host_ids.items()}
    columns["host"] = [names[i] for i in columns["host"]]
    send(conn, {"cpu_s": cpu, "seconds": wall, "counters": counters, "columns": columns})
