"""`skin run` under faults an outside injector makes on udp_multicast, with `skin sim run`
(three 3-axis patches) in another process and an independent listener here checking the
force nodes' PDOs: undecodable datagrams, error frames, SIGSTOP stalls of the host,
garbled SDO answers while a reset patch is configured again, an EMCY flood.

Recovery is counted in SYNCs the host sent (10 ms each) after the fault ended, as the
listener sees them: "within 3 s" is within 300 SYNCs, which a slow machine stretches in
wall time but cannot break. The tests share one run and go in order; the last reads its
--json, which tells what happened."""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import can
import pytest

from canbus.master.cobids import predefined_tpdo_cob_ids
from canbus.receiveloop import ReceiveLoop
from tests.canbus.faults import UdpInjector, rss_bytes, stall
from tests.support.rigs import children
from tests.support.rigs.children import Child
from tests.support.rigs.ports import udp_bus
from tests.support.rigs.waiting import wait_until

ROOT = Path(__file__).resolve().parents[2]
PATCHES = (1, 2, 3)
RECOVERY_SYNCS = 300
WAIT_S = 60.0
GARBAGE, ERROR_FRAMES, STALLS, EMCYS = 101, 20, 16, 12_000
EMCY_RATE = 3000  # per second, as in issue 20
STATE_LINE = re.compile(r"patch \d+: (absent|configuring|operational|lost|failed)\b")


@dataclass
class Watch:
    """SYNCs and the force nodes' last TPDO (0x2005 valid bits) as a listener sees them."""

    syncs: int = 0
    decoded: dict[int, int] = field(default_factory=dict)  # force node -> SYNC count
    bits: dict[int, int] = field(default_factory=dict)  # valid taxels of the last decoded
    lock: threading.Lock = field(default_factory=threading.Lock)

    def __post_init__(self) -> None:
        self.last_tpdo = {predefined_tpdo_cob_ids(n + 64)[-1]: n + 64 for n in PATCHES}

    def on_message_received(self, msg: can.Message) -> None:
        if msg.arbitration_id == 0x080:
            self.syncs += 1
            return
        force = self.last_tpdo.get(msg.arbitration_id)
        if force is not None and len(msg.data) == 8:
            bits = int.from_bytes(msg.data[6:8], "little") & 0x1FF
            if bits:
                with self.lock:
                    self.bits[force] = bits  # of the last decoded sample
                    self.decoded[force] = self.syncs

    def __call__(self, msg: can.Message) -> None:
        self.on_message_received(msg)

    def all_decoded_after(self, sync: int) -> bool:
        with self.lock:
            return all(self.decoded.get(n + 64, -1) > sync for n in PATCHES)

    def recovery(self, sync: int, what: str = "") -> int:
        """SYNCs after ``sync`` until every force node published a decoded sample (printed
        with ``what``: pytest -s shows the figures)."""
        began = time.monotonic()
        try:
            wait_until(lambda: self.all_decoded_after(sync), timeout=WAIT_S, interval=0.01,
                       what=f"every patch decoded after SYNC {sync}")
        except AssertionError as err:
            raise AssertionError(f"{err}; force node -> SYNC of its last decoded sample: "
                                 f"{self.decoded}") from None
        with self.lock:
            syncs = max(self.decoded[n + 64] for n in PATCHES) - sync
        if what:
            print(f"\n{what}: every patch decoded again {syncs} SYNCs "
                  f"({time.monotonic() - began:.2f} s) after the fault ended")
        return syncs


@dataclass
class Run:
    host: Child
    sim: Child
    watch: Watch
    inject: UdpInjector
    json: Path

    def output(self) -> str:
        """Both processes' output, for an assertion message (the module's children are not
        the test's own, so a failing test's report does not show them)."""
        return f"{self.host.output()}\n{self.sim.output()}"


def _skin(*argv: str) -> Child:
    return children.spawn([sys.executable, "-m", "skin.cli", *argv], cwd=ROOT,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Run]:
    folder = tmp_path_factory.mktemp("faults")
    group, port = udp_bus()
    config = folder / "host.toml"
    config.write_text(f'[host]\nscan_ms = 300\nsdo_timeout_ms = 300\n[bus]\n'
                      f'interface = "udp_multicast"\nchannel = "{group}"\n'
                      f"options = {{ port = {port} }}\n"
                      + "".join(f"[[patches]]\nnode_id = {n}\n" for n in PATCHES))
    watch = Watch()
    listener = can.Bus(interface="udp_multicast", channel=group, port=port)
    loop = ReceiveLoop(listener, [watch], timeout=0.05)  # the injector's garbage is ours too
    sim = _skin("sim", "run", "indenter", "--patches", str(len(PATCHES)), "-i",
                "udp_multicast", "-c", group, "--bus-kwargs", f"port={port}")
    host = _skin("run", str(config), "--json", str(folder / "run.json"))
    inject = UdpInjector(group, port)
    try:
        yield Run(host, sim, watch, inject, folder / "run.json")
    finally:
        inject.close()
        for process in (host, sim):
            process.send_signal(signal.SIGINT)
        for process in (host, sim):
            # Killed after the deadline (AssertionError): the tests said what failed.
            with contextlib.suppress(AssertionError):
                process.wait()
        loop.stop()
        listener.shutdown()


def test_the_host_runs_and_every_patch_is_decoded(run: Run) -> None:
    assert run.watch.recovery(0) >= 0
    assert run.host.running() and run.sim.running(), run.output()


def test_one_undecodable_datagram_and_the_host_hears_on(run: Run) -> None:
    run.inject.garbage(1)
    assert run.watch.recovery(run.watch.syncs, "one undecodable datagram") <= RECOVERY_SYNCS


def test_a_burst_of_garbage_and_error_frames_and_the_host_hears_on(run: Run) -> None:
    run.inject.garbage(GARBAGE - 1)
    run.inject.error_frames(ERROR_FRAMES)
    what = "100 undecodable datagrams and 20 error frames"
    assert run.watch.recovery(run.watch.syncs, what) <= RECOVERY_SYNCS
    assert run.host.running() and run.sim.running(), run.output()


def test_sigstop_stalls_of_the_host_and_every_beating_patch_is_back(run: Run) -> None:
    stall(run.host.pid, STALLS, 0.2, 0.3)
    assert run.watch.recovery(run.watch.syncs, "16 SIGSTOP stalls of 0.2 s") <= RECOVERY_SYNCS


def test_garbled_sdo_answers_while_a_reset_patch_is_configured_again(run: Run) -> None:
    stop = threading.Event()
    failed = "patch 3: set-up failed"
    before = run.host.stderr().count(failed)

    def garble() -> None:
        while not stop.is_set():
            run.inject.garbled_sdo(3)
            time.sleep(0.0005)  # pacing: about 2,000 garbled answers a second

    flood = threading.Thread(target=garble)
    flood.start()
    try:
        run.inject.nmt(0x81, 3)  # reset node 3: it boots, the host configures it again
        time.sleep(1.5)  # pacing: the fault lasts 1.5 s, as in the issue
        # ... and, on a machine too busy to have begun the set-up by then, until the
        # garbled answers have made one fail, which is the fault the host must survive.
        try:
            wait_until(lambda: run.host.stderr().count(failed) > before, timeout=WAIT_S,
                       what=f"{failed!r} on the host's stderr")
        except AssertionError as err:
            raise AssertionError(f"{err}\n{run.output()}") from None
    finally:
        stop.set()
        flood.join()
    what = "garbled SDO answers for 1.5 s during a reset"
    assert run.watch.recovery(run.watch.syncs, what) <= RECOVERY_SYNCS


def test_an_emcy_flood_never_reset_keeps_the_host_flat_and_publishing(run: Run) -> None:
    run.watch.recovery(run.watch.syncs)  # settled
    before = rss_bytes(run.host.pid)
    sent = run.inject.at_rate(EMCY_RATE, EMCYS, lambda k: run.inject.emcy(1, 0x5000, 4))
    # A force PDO answering a SYNC sent after the last EMCY: every EMCY was handled.
    assert run.watch.recovery(run.watch.syncs, "a 3,000/s EMCY flood") <= RECOVERY_SYNCS
    grown = rss_bytes(run.host.pid) - before
    assert sent == EMCYS
    assert grown < 2 << 20, f"{grown} bytes over {sent} EMCYs"  # unbounded: ~0.4 KiB each
    print(f"host RSS over {sent} EMCYs at {EMCY_RATE}/s: {grown / 1024:+.0f} KiB")
    with run.watch.lock:
        assert run.watch.bits[65] and not run.watch.bits[65] & 1 << 4  # taxel 4 masked


def test_the_json_tells_what_happened(run: Run) -> None:
    assert run.host.stop(signal.SIGINT) == 0, run.host.output()
    out, err = run.host.stdout(), run.host.stderr()
    record = json.loads(run.json.read_text())
    receive = record["buses"]["default"]["receive"]
    assert receive["errors"] >= GARBAGE + ERROR_FRAMES
    assert "could not unpack received message" in receive["last_error"]
    assert receive["gone"] is None and record["bus_gone"] is None
    patches = record["patches"]
    assert all(p["state"] == "operational" for p in patches.values()), patches
    assert patches["3"]["setup_failures"] >= 1  # the garbled answers, retried
    assert patches["3"]["history"][-1]["state"] == "operational"
    # UDP may drop a datagram when the host's socket buffer fills on a busy machine.
    assert patches["1"]["emcys"] >= 0.9 * EMCYS and patches["1"]["faulty_taxels"] == [4]
    # Every line of a state is printed once, on stdout.
    assert "patch 3: operational" in out.splitlines()
    assert not STATE_LINE.search(err), err
