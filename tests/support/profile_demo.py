"""Where ``skin demo``'s CPU goes: the demo run in this process, its threads' CPU counted.

    python -m tests.support.profile_demo [--profile-json F] DEMO-ARGS...
    python -m tests.support.profile_demo --patches 8 --buses 2
    python -m tests.support.profile_demo --patches 8 --buses 2 --bus virtual

Runs ``skin demo DEMO-ARGS`` and reports, over the demo's run (``seconds`` of its summary):

- the CPU of each group of threads (Linux: /proc/self/task), as a share of one core, which
  is what Python threads share through the GIL: the notifiers that read the buses (the
  host's and the patches'; they also run the timed wire and the patch server's answers),
  the data plane's publishing threads, the SYNC producers; the main thread (set-up, live
  view, summary) apart;
- the thread CPU spent inside chosen stages (``time.thread_time`` around each call, nested
  stages inside their callers): a bus's send and receive (on the timed bus including running
  the wire and the wake-ups), the data plane's publishing (decoding and sending the force
  frames) and its intake of a PDO, the patch server's answer to a SYNC, canopen's dispatch.

The counters cost about a microsecond per call: compare the timed bus with ``--bus virtual``
under the same counters, not with an uncounted run.
"""

from __future__ import annotations

import argparse
import collections
import functools
import json
import os
import sys
import threading
import time
from typing import Any

_TICK = os.sysconf("SC_CLK_TCK")
_GROUPS = {"Notifier": "notifier threads (bus readers)", "dataplane": "data plane threads",
           "sync-producer": "SYNC producers", "MainThread": "main thread (set-up, view)"}


def _thread_cpu(tid: int) -> float | None:
    try:
        with open(f"/proc/self/task/{tid}/stat", encoding="ascii") as handle:
            fields = handle.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / _TICK


class _Stages:
    """Thread CPU inside wrapped methods, per label."""

    def __init__(self) -> None:
        self.ns: collections.Counter[str] = collections.Counter()
        self.calls: collections.Counter[str] = collections.Counter()

    def wrap(self, owner: Any, name: str, label: str) -> None:
        method = getattr(owner, name, None)
        if method is None:
            return
        ns, calls, clock = self.ns, self.calls, time.thread_time_ns

        @functools.wraps(method)
        def counted(*args: Any, **kwargs: Any) -> Any:
            start = clock()
            try:
                return method(*args, **kwargs)
            finally:
                ns[label] += clock() - start
                calls[label] += 1

        setattr(owner, name, counted)


def _instrument(stages: _Stages) -> dict[str, Any]:
    import can.interfaces.virtual
    import canopen.network

    import skin.commands.demo.summary
    from canbus.device import patch_server
    from canbus.master import dataplane, publisher
    from canbus.timed import wire

    stages.wrap(wire.Wire, "receive", "bus recv (timed: running the wire, wake-ups)")
    stages.wrap(wire.Wire, "_wait", "  of which asleep-and-woken (timed)")
    stages.wrap(wire.Wire, "_process", "  timed wire's own work (recv and send)")
    stages.wrap(wire.Wire, "submit", "bus send (timed)")
    stages.wrap(can.interfaces.virtual.VirtualBus, "_recv_internal", "bus recv (virtual)")
    stages.wrap(can.interfaces.virtual.VirtualBus, "send", "bus send (virtual)")
    stages.wrap(publisher.Publisher, "publish", "data plane: decode and publish a batch")
    stages.wrap(publisher.Publisher, "_send", "  of which the force frames sent")
    stages.wrap(dataplane.DataPlane, "take", "data plane: a PDO taken in")
    stages.wrap(patch_server.PatchServer, "_answer", "patch server: a SYNC's answer sent")
    stages.wrap(canopen.network.MessageListener, "on_message_received",
                "canopen: a frame dispatched (patches' side)")
    record: dict[str, Any] = {}
    summary = skin.commands.demo.summary.summary

    def keep(*args: Any, **kwargs: Any) -> dict[str, Any]:
        result: dict[str, Any] = summary(*args, **kwargs)
        record.update(result)
        return result

    skin.commands.demo.summary.summary = keep
    return record


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--profile-json", metavar="FILE", help="write the figures here")
    args, demo_args = parser.parse_known_args()
    from skin.cli import main as skin_main

    stages = _Stages()
    record = _instrument(stages)
    last: dict[tuple[int, str], float] = {}
    stop = threading.Event()

    def watch() -> None:  # a thread's CPU is read while it lives; the last reading stays
        while not stop.wait(0.1):
            for thread in threading.enumerate():
                if thread.native_id is not None and thread is not watcher:
                    cpu = _thread_cpu(thread.native_id)
                    if cpu is not None:
                        last[(thread.native_id, thread.name)] = cpu

    watcher = threading.Thread(target=watch, name="profile-watch", daemon=True)
    watcher.start()
    process = time.process_time()
    status = skin_main(["demo", *demo_args])
    process = time.process_time() - process
    stop.set()
    watcher.join()
    seconds = float(record.get("seconds") or "nan")
    groups: dict[str, float] = collections.defaultdict(float)
    for (_, name), cpu in last.items():
        group = next((g for key, g in _GROUPS.items() if name.startswith(key)), "other threads")
        groups[group] += cpu
    run = sum(cpu for group, cpu in groups.items() if group != _GROUPS["MainThread"])
    print(f"\nrun {seconds:.2f} s; process CPU {process:.2f} s (set-up included); threads "
          f"of the run {run:.2f} s = {100 * run / seconds:.0f} % of one core", file=sys.stderr)
    for group, cpu in sorted(groups.items(), key=lambda item: -item[1]):
        print(f"  {cpu:6.2f} s  {100 * cpu / seconds:5.1f} %  {group}", file=sys.stderr)
    print("stages (thread CPU inside each call):", file=sys.stderr)
    for label, ns in stages.ns.most_common():
        calls = stages.calls[label]
        print(f"  {ns / 1e9:6.3f} s {calls:8,d} calls {ns / 1e3 / calls:8.1f} us/call  {label}",
              file=sys.stderr)
    if args.profile_json:
        figures = {"demo_args": demo_args, "run_s": seconds, "process_cpu_s": process,
                   "run_threads_cpu_s": run, "groups_cpu_s": dict(groups),
                   "stages": {label: {"cpu_s": ns / 1e9, "calls": stages.calls[label]}
                              for label, ns in stages.ns.items()},
                   "demo": record}
        with open(args.profile_json, "w", encoding="utf-8") as handle:
            json.dump(figures, handle, indent=2)
    sys.exit(status)


if __name__ == "__main__":
    main()
