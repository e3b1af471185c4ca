"""A reader of the skin on Zenoh written from docs/zenoh.md alone: raw ``zenoh`` and
``struct``, nothing of canskin. ``python examples/zenoh_raw_reader.py ENDPOINT KEYEXPR COUNT OUT``
subscribes to KEYEXPR on a session connected to ENDPOINT (no scouting), decodes COUNT
force samples by the documented layout and writes them as JSON lines to OUT."""

import json
import struct
import sys
import threading

import zenoh


def decode(payload):
    """The documented schema version 1 -> a dict (raises ValueError if it is not one)."""
    if len(payload) < 40:
        raise ValueError("short")
    (version, flags, patch, force_node, counter, taxels, axes, _reserved, cycle, t_sync,
     t_published, t_sent) = struct.unpack_from("<8BQ3d", payload, 0)
    if version != 1:
        raise ValueError(f"version {version}")
    at = 40
    n = taxels * axes
    forces = struct.unpack_from(f"<{n}d", payload, at)
    at += 8 * n
    reasons = list(payload[at:at + taxels])
    at += taxels
    (valid_bits,) = struct.unpack_from("<H", payload, at)
    at += 2
    names = []
    for _ in range(2):
        length = payload[at]
        names.append(payload[at + 1:at + 1 + length].decode("utf-8"))
        at += 1 + length
    extensions = []
    while at < len(payload):
        tag, length = struct.unpack_from("<BH", payload, at)
        extensions.append(tag)  # unknown tags are skipped, as the docs say
        at += 3 + length
    return {
        "host": names[0], "bus": names[1], "patch": patch, "force_node": force_node,
        "cycle": cycle, "sync_counter": counter, "sync_time": t_sync,
        "published_time": t_published, "sent_time": t_sent,
        "complete": bool(flags & 1), "published": bool(flags & 2),
        "forces": [list(forces[k * axes:(k + 1) * axes]) for k in range(taxels)],
        "reasons": reasons,
        "valid": [bool(valid_bits >> k & 1) for k in range(taxels)],
        "extensions": extensions,
    }


def main():
    endpoint, key, count, out = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("listen/endpoints", "[]")
    config.insert_json5("scouting/multicast/enabled", "false")
    samples = []
    done = threading.Event()

    def on_sample(sample):
        if len(samples) < count:
            record = decode(sample.payload.to_bytes())
            record["key"] = str(sample.key_expr)
            record["encoding"] = str(sample.encoding)
            samples.append(record)
        if len(samples) >= count:
            done.set()

    with zenoh.open(config) as session:
        subscriber = session.declare_subscriber(key, on_sample)
        print("subscribed", flush=True)
        finished = done.wait(30.0)
        subscriber.undeclare()
    with open(out, "w", encoding="utf-8") as handle:
        for record in samples:
            handle.write(json.dumps(record) + "\n")
    sys.exit(0 if finished else 3)


if __name__ == "__main__":
    main()
