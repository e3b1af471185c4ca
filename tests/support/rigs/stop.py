"""Three recorders of one udp_multicast bus, stopped while frames flow (tests and figures).

One sender (the calling process) numbers every frame. `can.logger -f`, `skin sniff
--record` ended by SIGTERM and `skin sniff --record` ended by SIGKILL run as processes of
their own; both signals go at the same moment. can.logger has no SIGTERM handler, so it
dies with its buffered tail unwritten (and, for .blf, with the header it wrote at the
start); its recording is read with ``partial=True``, as is the killed one.

    python -m tests.support.rigs.stop [--format asc] [--rate 2000] [--seconds 2]

prints the counts as JSON (the figures of docs/sniffer.md).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import can

from canbus.tools.recording import Recording
from tests.support.rigs.children import Child, spawn
from tests.support.rigs.ports import udp_bus

IDS = frozenset((0x181, 0x182, 0x183))


@dataclass
class StopRun:
    """What each recorder kept of ``sent`` numbered frames (numbers in file order)."""

    sent: int
    sent_before_signal: int
    sent_before: dict[float, int]  # seconds before the signals -> frames sent until then
    termed: list[int] = field(repr=False)
    termed_json: dict[str, object] = field(repr=False)
    termed_stdout: str = field(repr=False)
    logger: list[int] = field(repr=False)
    killed: list[int] = field(repr=False)
    killed_path: Path = field(repr=False)


def numbers(path: Path, *, partial: bool) -> list[int]:
    with Recording(path, partial=partial) as recording:
        return [int.from_bytes(m.data, "little") for m in recording
                if m.arbitration_id in IDS and len(m.data) == 4]


def _send(bus: can.BusABC, rate: float, seconds: float, signal_at: float,
          stop: list[Child], kill: Child) -> tuple[float, list[float]]:
    """Numbered frames at ``rate`` for ``seconds``; at ``signal_at`` SIGTERM ``stop`` and
    SIGKILL ``kill``. (when the signals went, when each frame went)."""
    sent_at: list[float] = []
    signalled = 0.0
    started = time.monotonic()
    while (now := time.monotonic()) - started < seconds:
        if not signalled and now - started >= signal_at:
            signalled = time.monotonic()
            for proc in stop:
                proc.send_signal(signal.SIGTERM)
            kill.send_signal(signal.SIGKILL)
        due = int((now - started) * rate)
        while len(sent_at) < due:
            k = len(sent_at)
            bus.send(can.Message(arbitration_id=0x181 + k % 3, data=k.to_bytes(4, "little"),
                                 is_extended_id=False))
            sent_at.append(time.monotonic())
        time.sleep(0.001)  # pacing: the frames go out at ``rate``
    return signalled, sent_at


def run(suffix: str, channel: str, port: int, folder: Path, *, rate: float = 2000,
        seconds: float = 2.0, signal_at: float = 1.6) -> StopRun:
    bus_args = ["-i", "udp_multicast", "-c", channel, "--bus-kwargs", f"port={port}"]
    theirs, termed, killed = (folder / f"{name}{suffix}" for name in
                              ("logger", "termed", "killed"))
    summary = folder / "termed.json"
    sniff = [sys.executable, "-m", "skin.cli", "sniff", *bus_args, "--view", "none"]
    env = os.environ | {"PYTHONUNBUFFERED": "1"}  # can.logger's "Connected to" line
    procs = [spawn([sys.executable, "-m", "can.logger", *bus_args, "-f", str(theirs)], env=env),
             spawn([*sniff, "--record", str(termed), "--json", str(summary)]),
             spawn([*sniff, "--record", str(killed)])]
    try:
        procs[0].wait_for("Connected to", timeout=60)
        for proc in procs[1:]:  # the line comes once the sniffer receives
            proc.wait_for("Ctrl-C stops", timeout=60)  # --view none: stdout
        with can.Bus(interface="udp_multicast", channel=channel, port=port) as bus:
            signalled, sent_at = _send(bus, rate, seconds, signal_at, procs[:2], procs[2])
        codes = [proc.wait() for proc in procs]
    finally:
        for proc in procs:
            if proc.running():
                proc.kill()
    if codes[1] != 0 or codes[2] != -signal.SIGKILL:
        raise RuntimeError(f"skin sniff ended with {codes[1:]}: {procs[1].output()}")
    stdout = procs[1].stdout()
    return StopRun(
        sent=len(sent_at), sent_before_signal=sum(t <= signalled for t in sent_at),
        sent_before={lead: sum(t <= signalled - lead for t in sent_at) for lead in (0.5, 1.0)},
        termed=numbers(termed, partial=False), termed_json=json.loads(summary.read_text()),
        termed_stdout=stdout, logger=numbers(theirs, partial=True),
        killed=numbers(killed, partial=True), killed_path=killed)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--format", choices=("log", "asc", "blf", "pcap"), default="asc")
    parser.add_argument("--rate", type=float, default=2000)
    parser.add_argument("--seconds", type=float, default=2.0)
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)  # the cut tails are counted below
    channel, port = udp_bus()
    with tempfile.TemporaryDirectory() as tmp:
        result = run(f".{args.format}", channel, port, Path(tmp), rate=args.rate,
                     seconds=args.seconds, signal_at=0.8 * args.seconds)
    sent_then = result.sent_before_signal
    record = {k: v for k, v in asdict(result).items()
              if k in ("sent", "sent_before_signal")}
    for name in ("termed", "logger", "killed"):
        kept: list[int] = getattr(result, name)
        record[name] = {"frames": len(kept),
                        "lost_before_the_signal": sent_then - sum(k < sent_then for k in kept)}
    print(json.dumps({"format": args.format, "rate": args.rate} | record, indent=2))


if __name__ == "__main__":
    main()
