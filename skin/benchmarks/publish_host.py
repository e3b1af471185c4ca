"""One host process of ``skin bench publish``: a ``HostManager`` on its udp_multicast bus,
publishing on Zenoh through :class:`~canbus.zenoh.publisher.ZenohPublisher`.

Driven over a pipe with msgpack messages: it says ``ready`` once its patches are
operational, takes ``measure`` (the window starts: CPU, counters and SYNC cycle noted)
and ``stop`` (the window ends), then answers with the window's figures and exits.
"""

from __future__ import annotations

import gc
import time
from multiprocessing.connection import Connection
from typing import Any

import msgpack

READY_TIMEOUT_S = 60.0
HEARTBEAT_MS = 1000
RCVBUF = 4 << 20
"""The patches' heartbeat: on a machine shared with other work a 100 ms heartbeat was
overdue (1.5 periods) often enough to lose patches mid-run; the data path is the same."""


def send(conn: Connection, message: dict[str, Any]) -> None:
    conn.send_bytes(msgpack.packb(message))


def receive(conn: Connection) -> dict[str, Any]:
    message: dict[str, Any] = msgpack.unpackb(conn.recv_bytes(), raw=False)
    return message


def host_main(conn: Connection, index: int, group: str, port: int, patch_ids: list[int],
              listen: str, express: bool) -> None:
    """The process's whole life (spawned by ``run_publish_benchmark``)."""
    import can

    from canbus.master.busconfig import BusConfig
    from canbus.master.host import HostManager
    from canbus.master.hostconfig import HostConfig, PatchConfig
    from canbus.master.zenoh_settings import ZenohSettings
    from canbus.rxbuffer import enlarge_receive_buffer
    from canbus.zenoh.publisher import ZenohPublisher

    name = f"bus{index}"
    config = HostConfig(
        patches=tuple(PatchConfig(n, bus=name) for n in patch_ids),
        buses=(BusConfig(name=name, interface="udp_multicast", channel=group,
                         options={"port": port}),),
        scan_ms=300, sdo_timeout_ms=5000, heartbeat_ms=HEARTBEAT_MS)
    settings = ZenohSettings(listen=(listen,), host=f"host{index}", express=express)
    bus = can.Bus(interface="udp_multicast", channel=group, port=port)
    enlarge_receive_buffer(bus, RCVBUF)  # as skin run does
    try:
        host = HostManager(bus, config)
        publisher = ZenohPublisher(host, settings, measure_cpu=True)
        gc.collect()
        gc.freeze()
        with publisher, host:
            ok = _operational(host)
            send(conn, {"ready": ok, "health": {str(k): v.state
                                                for k, v in host.health().items()}})
            receive(conn)  # measure
            start = _snapshot(host, publisher)
            receive(conn)  # stop
            end = _snapshot(host, publisher)
            result = _window(start, end)
        result["zenoh"] = publisher.counters()
        result["host_stats"] = host.stats()
        send(conn, result)
    finally:
        bus.shutdown()


def _operational(host: Any, attempts: int = 3) -> bool:
    """Every patch operational; a patch whose set-up failed (an SDO answer lost on a busy
    machine) is reset by NMT, so that it boots and is configured again."""
    for _ in range(attempts):
        if host.wait_operational(timeout=READY_TIMEOUT_S / attempts):
            return True
        for node_id, health in host.health().items():
            if health.state == "failed":
                host.patches[node_id].node.nmt.send_command(0x81)  # reset node
    return bool(host.wait_operational(timeout=READY_TIMEOUT_S / attempts))


def _snapshot(host: Any, publisher: Any) -> dict[str, Any]:
    stats = host.stats()
    return {"wall": time.monotonic(), "cpu": time.process_time(),
            "publish": publisher.cpu_seconds(), "cycle": host.sync.cycle,
            "samples": stats["samples"], "complete": stats["complete_samples"],
            "frames_received": stats["frames_in"] + stats["bus_frames"]
            + stats["unknown_frames"], "frames_sent": stats["frames_out"],
            "sent": publisher.sent, "dropped": publisher.queue.dropped}


def _window(start: dict[str, Any], end: dict[str, Any]) -> dict[str, Any]:
    publish = {k: end["publish"][k] - start["publish"][k] for k in start["publish"]}
    return {"first_cycle": start["cycle"] + 1, "last_cycle": end["cycle"],
            "seconds": end["wall"] - start["wall"], "cpu_s": end["cpu"] - start["cpu"],
            "publish_cpu_s": publish, "samples": end["samples"] - start["samples"],
            "complete": end["complete"] - start["complete"],
            "frames_received": end["frames_received"] - start["frames_received"],
            "frames_sent": end["frames_sent"] - start["frames_sent"],
            "sent": end["sent"] - start["sent"], "dropped": end["dropped"] - start["dropped"]}
