"""A live run recorded to MCAP, as a user runs it: ``skin sim run`` (N patches),
``skin run --record run.mcap --zenoh`` (the host's API, the force samples on Zenoh, read
here) and ``skin sniff --record beside.log`` on one udp_multicast bus over loopback.

``python -m tests.support.rigs.mcap_run SECONDS [PATCHES]`` is the hand check: it prints what
:func:`compare` finds.
"""

from __future__ import annotations

import json
import signal
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path

import can
import numpy as np

from canbus.master.channel import ForceFrame
from tests.support.rigs.children import spawn
from tests.support.rigs.ports import tcp_port, udp_bus
from tests.support.rigs.waiting import wait_until

SKIN = [sys.executable, "-m", "skin.cli"]


@dataclass
class McapRun:
    mcap: Path
    log: Path
    host_json: dict[str, object]
    api: list[ForceFrame] = field(default_factory=list)  # what Zenoh gave of the host's API


def host_toml(channel: str, port: int, patches: int, zenoh_port: int) -> str:
    rows = "".join(f"[[patches]]\nnode_id = {n}\nposition_m = [0.0, {0.05 * (n - 1):.2f}]\n"
                   f"orientation_deg = {30.0 * (n - 1):.1f}\n" for n in range(1, patches + 1))
    return (f"[host]\nheartbeat_ms = 500\n[bus]\ninterface = \"udp_multicast\"\n"
            f"channel = \"{channel}\"\noptions = {{ port = {port} }}\n{rows}"
            f"[zenoh]\nhost = \"mcap-host\"\nlisten = [\"tcp/127.0.0.1:{zenoh_port}\"]\n")


def live_run(folder: Path, seconds: float, patches: int = 4) -> McapRun:
    """Record ``seconds`` of steady traffic; SIGTERM ends the host, then the sniffer."""
    from canbus.master.zenoh_settings import ZenohSettings
    from canbus.zenoh.reader import subscribe

    channel, port = udp_bus()
    zport = tcp_port()
    config = folder / "host.toml"
    config.write_text(host_toml(channel, port, patches, zport))
    mcap, log, out = folder / "run.mcap", folder / "beside.log", folder / "host.json"
    bus = ["-i", "udp_multicast", "-c", channel, "--bus-kwargs", f"port={port}"]
    sniff = spawn([*SKIN, "sniff", *bus, "--record", str(log), "--view", "none"])
    sniff.wait_for("capturing", timeout=60)
    sim = spawn([*SKIN, "sim", "run", "indenter", "--patches", str(patches), *bus])
    host = spawn([*SKIN, "run", str(config), "--record", str(mcap), "--json", str(out)])
    api: list[ForceFrame] = []
    try:
        host.wait_for("zenoh: publishing", timeout=60)
        with subscribe(settings=ZenohSettings(connect=(f"tcp/127.0.0.1:{zport}",))) as sub:
            done = threading.Event()

            def keep() -> None:  # until the host stopped and nothing more came for 1 s
                while True:
                    api.extend(sub.frames(timeout=1.0))
                    if done.is_set():
                        return

            reader = threading.Thread(target=keep, daemon=True)
            reader.start()
            wait_until(lambda: len(api) >= 100 * patches * seconds,
                       what=f"{seconds} s of samples on Zenoh", timeout=120 + 2 * seconds)
            host.stop(signal.SIGTERM)
            done.set()
            reader.join(30)
    finally:
        host.stop(signal.SIGTERM)
        sim.stop(signal.SIGTERM)
        sniff.stop(signal.SIGTERM)
    assert host.returncode == 0, host.output()
    return McapRun(mcap, log, json.loads(out.read_text()), api)


def frames_key(msg: can.Message) -> tuple[object, ...]:
    return (msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, msg.is_fd, msg.dlc,
            bytes(msg.data))


def not_a_run_of(part: list[tuple[object, ...]], whole: list[tuple[object, ...]]) -> str:
    """"" if ``part`` holds, identifier by identifier, a run of ``whole``'s frames: each
    identifier has one sender, whose frames every socket gets in its order, while frames
    of two senders that crossed may reach two sockets in either order. Else what differs."""
    def by_id(frames: list[tuple[object, ...]]) -> dict[object, list[tuple[object, ...]]]:
        out: dict[object, list[tuple[object, ...]]] = {}
        for frame in frames:
            out.setdefault(frame[0], []).append(frame)
        return out

    ours, theirs = by_id(part), by_id(whole)
    for can_id, frames in ours.items():
        other = theirs.get(can_id, [])
        if not any(other[k:k + len(frames)] == frames for k, f in enumerate(other)
                   if f == frames[0]):
            return f"0x{can_id:X}: {len(frames)} frames, not a run of the .log's {len(other)}"
    return ""


def same_frame(a: ForceFrame, b: ForceFrame) -> bool:
    """Equal bit for bit in every field the API gives (the contact summary aside)."""
    return (a.patch, a.force_node, a.cycle, a.sync_counter, a.complete, a.published) == \
        (b.patch, b.force_node, b.cycle, b.sync_counter, b.complete, b.published) and \
        np.float64(a.timestamp).tobytes() == np.float64(b.timestamp).tobytes() and \
        a.force_N.astype(np.float64).tobytes() == b.force_N.astype(np.float64).tobytes() and \
        np.array_equal(a.valid, b.valid) and np.array_equal(a.reason, b.reason)


def main() -> None:
    import tempfile

    from canbus.offline.mcap import read_forces
    from canbus.tools.recording import Recording

    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 10.0
    patches = int(sys.argv[2]) if len(sys.argv) > 2 else 4
    with tempfile.TemporaryDirectory() as folder:
        run = live_run(Path(folder), seconds, patches)
        recorded = {(f.patch, f.cycle): f for f in read_forces(str(run.mcap))}
        equal = sum(same_frame(f, recorded[(f.patch, f.cycle)]) for f in run.api
                    if (f.patch, f.cycle) in recorded)
        with Recording(run.mcap) as rec:
            ours = [frames_key(m) for m in rec]
        with Recording(run.log) as rec:
            beside = [frames_key(m) for m in rec]
        differ = not_a_run_of(ours, beside)
        print(f"{len(recorded)} samples in the MCAP ({run.mcap.stat().st_size:,} bytes), "
              f"host published {run.host_json['stats']['samples']} "  # type: ignore[index]
              f"({run.host_json['steady_complete_pct']} % complete in the steady state); "
              f"{equal} of {len(run.api)} Zenoh samples equal bit for bit; "
              f"{len(ours)} frames, " + (differ or "sender by sender a run of the .log's"))


if __name__ == "__main__":
    main()
