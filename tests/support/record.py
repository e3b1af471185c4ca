"""Benchmark: does ``skin sniff --record`` keep every frame at 20,000 frames/s?

    python -m tests.support.record [--rate 20000] [--seconds 5] [--format pcap]
                                        [--view live] [--interface udp_multicast]

udp_multicast (default): ``skin sniff`` runs as its own process, its stdout on a
pseudo-terminal so the rich live view really draws; this process sends CANopen-shaped
traffic at ``--rate`` frames/s (a SYNC with counter, then 7 TPDOs of each of 16 patches,
every payload numbered), paced in 1 ms slices. The recording is read back and must hold
every frame sent, in order, byte for byte. The figure therefore includes python-can's
udp_multicast send and receive (msgpack per frame, one datagram each, kernel loopback),
the sniffer's counters and event decoding, the live view and the recording thread.

virtual: sender thread and ``Sniffer`` + ``Recorder`` in this one process on python-can's
virtual bus (no view): the in-process ceiling, without sockets.

writer: the recorder alone, no bus: ``--seconds x --rate`` frames handed to a
``Recorder`` as fast as possible, written out and closed; the recorder's frames per
CPU-second (all its threads), best of three.

Prints one JSON object: sent, recorded, lost, the achieved send rate, and the view's
redraws and skipped redraws from the sniffer's own ``--json`` summary.
"""

from __future__ import annotations

import argparse
import json
import os
import pty
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import can

PATCHES, TPDOS = 16, (0x180, 0x280, 0x380, 0x480, 0x200, 0x300, 0x400)


def frames(count: int) -> list[can.Message]:
    """``count`` frames: SYNC (counter 1..240) then 16 patches x 7 TPDOs, numbered payloads."""
    out: list[can.Message] = []
    sync = 0
    while len(out) < count:
        sync = sync % 240 + 1
        out.append(can.Message(arbitration_id=0x080, data=bytes([sync]), is_extended_id=False))
        for node in range(1, PATCHES + 1):
            for base in TPDOS:
                payload = len(out).to_bytes(4, "little") + bytes(4)
                out.append(can.Message(arbitration_id=base + node, data=payload,
                                       is_extended_id=False))
    return out[:count]


def send_paced(bus: can.BusABC, messages: list[can.Message], rate: float) -> float:
    """Send at ``rate`` frames/s in 1 ms slices; the seconds it took."""
    per_slice = max(1, round(rate / 1000))
    started = time.perf_counter()
    for start in range(0, len(messages), per_slice):
        due = started + start / rate
        pause = due - time.perf_counter()
        if pause > 0:
            time.sleep(pause)
        for msg in messages[start:start + per_slice]:
            bus.send(msg)
    return time.perf_counter() - started


def check(path: Path, sent: list[can.Message]) -> tuple[int, int]:
    """(our frames, foreign frames) in the recording; raises if ours are out of order.

    On Linux a socket bound to udp_multicast's port receives every group joined on that
    port by any process, so other tests' traffic can show up: it is counted, not ours.
    """
    from canbus.tools.recording import Recording

    index = {(m.arbitration_id, bytes(m.data)): k for k, m in enumerate(sent)
             if m.arbitration_id != 0x080}  # TPDO payloads are numbered; SYNCs repeat
    syncs, got = 0, []
    with Recording(path) as recording:
        for msg in recording:
            if msg.arbitration_id == 0x080 and len(msg.data) == 1:
                syncs += 1
            else:
                got.append(index.get((msg.arbitration_id, bytes(msg.data)), -1))
    ours = [k for k in got if k >= 0]
    if ours != sorted(set(ours)):
        raise SystemExit("the recorded frames are not in the order sent")
    return syncs + len(ours), len(got) - len(ours)


def bench_udp(args: argparse.Namespace, folder: Path) -> dict[str, object]:
    channel = f"239.74.{os.getpid() % 250}.{(os.getpid() // 250) % 250 + 1}"
    port = 20000 + os.getpid() % 20000  # a group alone does not isolate: own port too
    out = folder / f"bench.{args.format}"
    summary = folder / "sniff.json"
    messages = frames(int(args.rate * args.seconds))
    master, slave = pty.openpty()
    env = os.environ | {"COLUMNS": "160", "LINES": "48"}
    sniff = subprocess.Popen(
        [sys.executable, "-m", "skin.cli", "sniff", "-i", "udp_multicast", "-c", channel,
         "--bus-kwargs", f"port={port}", "--record", str(out), "--view", args.view,
         "--refresh", str(args.refresh), "--rcvbuf", str(args.rcvbuf),
         "--seconds", str(args.seconds + 4),
         "--json", str(summary)], stdin=subprocess.DEVNULL, stdout=slave, stderr=slave,
        env=env)
    os.close(slave)
    drain = threading.Thread(target=_drain, args=(master,), daemon=True)
    drain.start()
    deadline = time.monotonic() + 30
    while not out.exists():
        if time.monotonic() > deadline or sniff.poll() is not None:
            raise SystemExit("skin sniff did not start")
        time.sleep(0.05)
    time.sleep(0.5)  # the Notifier thread starts right after the recording file
    with can.Bus(interface="udp_multicast", channel=channel, port=port) as bus:
        took = send_paced(bus, messages, args.rate)
    sniff.wait(timeout=args.seconds + 60)
    recorded, foreign = check(out, messages)
    record = json.loads(summary.read_text())
    view = record["view"]
    return {"interface": "udp_multicast", "format": args.format, "view": args.view,
            "sent": len(messages), "recorded": recorded, "lost": len(messages) - recorded,
            "foreign": foreign,
            "send_rate": len(messages) / took, "sniff_cpu_share": record["cpu_share"],
            "refresh": args.refresh, "redraws": view["redraws"],
            "redraws_skipped": view["redraws_skipped"], "lines": view["lines"],
            "lines_dropped": view["lines_dropped"]}


def bench_virtual(args: argparse.Namespace, folder: Path) -> dict[str, object]:
    from canbus.tools.recorder import Recorder
    from canbus.tools.sniffer import Sniffer

    out = folder / f"bench.{args.format}"
    messages = frames(int(args.rate * args.seconds))
    rx = can.Bus(interface="virtual", channel="bench")
    tx = can.Bus(interface="virtual", channel="bench")
    recorder = Recorder(out)
    notifier = can.Notifier(rx, [recorder, Sniffer()], timeout=0.05)
    took = send_paced(tx, messages, args.rate)
    while recorder.received < len(messages):
        time.sleep(0.05)
    notifier.stop()
    tx.shutdown()
    rx.shutdown()
    recorded, _ = check(out, messages)
    return {"interface": "virtual", "format": args.format, "view": "none",
            "sent": len(messages), "recorded": recorded, "lost": len(messages) - recorded,
            "send_rate": len(messages) / took}


def bench_writer(args: argparse.Namespace, folder: Path) -> dict[str, object]:
    from canbus.tools.recorder import Recorder

    out = folder / f"bench.{args.format}"
    messages = frames(int(args.rate * args.seconds))
    for k, msg in enumerate(messages):
        msg.timestamp = 1.7e9 + k / args.rate
    best = float("inf")
    for _ in range(3):
        recorder = Recorder(out)
        cpu = time.process_time()
        for msg in messages:
            recorder.on_message_received(msg)
        recorder.stop()
        best = min(best, time.process_time() - cpu)
    recorded, _ = check(out, messages)
    return {"interface": "none (writer only)", "format": args.format, "sent": len(messages),
            "recorded": recorded, "frames_per_cpu_s": len(messages) / best}


def _drain(fd: int) -> None:
    try:
        while os.read(fd, 65536):
            pass
    except OSError:
        pass


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=20_000)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--format", choices=("log", "asc", "blf", "pcap", "mcap"), default="pcap")
    parser.add_argument("--view", choices=("live", "lines", "none"), default="live")
    parser.add_argument("--refresh", type=float, default=4.0, help="live view redraws/s")
    parser.add_argument("--rcvbuf", type=int, default=4 * 1024 * 1024,
                        help="skin sniff --rcvbuf (0: the system's default)")
    parser.add_argument("--interface", choices=("udp_multicast", "virtual", "writer"),
                        default="udp_multicast")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        run = {"udp_multicast": bench_udp, "virtual": bench_virtual,
               "writer": bench_writer}[args.interface]
        print(json.dumps(run(args, Path(tmp)), indent=2))


if __name__ == "__main__":
    main()
