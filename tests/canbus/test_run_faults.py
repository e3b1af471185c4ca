"""The commands when a bus is gone for good, or a stop comes at a bad moment: exit status
1 and one line, and the command ends by itself (it gives the bus up after
``canbus.busio.GIVE_UP_S``: 3 s, the "within 5 s" of issue 20, whose time ``pytest -s``
prints); --seconds and SIGTERM end a run whatever the host is doing (a 10-minute scan,
ended within a wait of seconds); no bus anywhere is one line naming the three ways to give
one. Every wait has a deadline of seconds that only a command which does not end reaches."""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import canopen
import pytest

from canbus.device.patch_server import PatchServer
from skin.cli import main
from tests.canbus.faults import GONE, gone_bus_registered
from tests.support.rigs import children
from tests.support.rigs.host import press, source
from tests.support.rigs.waiting import wait_until

ROOT = Path(__file__).resolve().parents[2]
WAIT_S = 30.0
LONGEST_SCAN_MS = 600_000  # the longest scan a config may ask for: 10 minutes


@pytest.fixture
def patch_on(request: pytest.FixtureRequest) -> Iterator[str]:
    """Patch 1 on a virtual channel, which interface ``gone`` reaches; yields the channel."""
    channel = f"gone-{request.node.name}"
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05
    net.connect(interface="virtual", channel=channel)
    server = PatchServer(net, source(1, press({})))
    server.start()
    with gone_bus_registered():
        yield channel
    server.stop()
    net.disconnect()


class Command:
    """``skin ARGV`` in a thread; its output read as it comes."""

    def __init__(self, argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
        self.capsys = capsys
        self.out = self.err = ""
        self.argv = argv
        self.code: list[int] = []
        self.thread = threading.Thread(target=lambda: self.code.append(main(argv)))
        self.thread.start()

    def read(self) -> None:
        captured = self.capsys.readouterr()
        self.out += captured.out
        self.err += captured.err

    def wait_for(self, text: str) -> None:
        def seen() -> bool:
            running = self.thread.is_alive()  # before reading: a last line is not missed
            self.read()
            assert text in self.out + self.err or running, \
                f"ended without {text!r}: {self.out + self.err!r}"
            return text in self.out + self.err

        wait_until(seen, what=f"{text!r} in the command's output", timeout=WAIT_S,
                   interval=0.02)

    def end(self) -> int:
        """Its exit status, once it ended by itself (AssertionError if it runs on)."""
        began = time.monotonic()
        wait_until(lambda: not self.thread.is_alive(), what="the command's end",
                   timeout=WAIT_S, interval=0.02)
        self.thread.join()
        self.read()
        print(f"\nskin {self.argv[0]}: exit {self.code[0]}, "
              f"{time.monotonic() - began:.2f} s after the wait for its end began")
        return self.code[0]


def _one_error_line(err: str) -> str:
    assert "Traceback" not in err
    errors = [line for line in err.splitlines() if line.startswith("skin: error: ")]
    assert len(errors) == 1, err
    assert err.splitlines()[-1] == errors[0]
    return errors[0]


def test_skin_run_on_a_bus_gone_for_good_gives_it_up_and_exits_1_with_one_line(
        patch_on: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "host.toml"
    config.write_text("[host]\nscan_ms = 100\n[[patches]]\nnode_id = 1\n")
    out = tmp_path / "run.json"
    run = Command(["run", str(config), "-i", "gone", "-c", patch_on, "--json", str(out)],
                  capsys)
    run.wait_for("patch 1: operational")
    GONE.set()  # ENETDOWN from recv, and the interface cannot be opened again
    assert run.end() == 1, run.out + run.err
    line = _one_error_line(run.err)
    assert line.startswith(f"skin: error: bus default (gone:{patch_on}): gone (")
    assert line.endswith("the host cannot hear its patches")
    record = json.loads(out.read_text())  # written first: it tells what happened
    assert record["bus_gone"] is not None
    assert record["buses"]["default"]["receive"]["failed_opens"] >= 1


def test_skin_sniff_on_a_bus_gone_for_good_gives_it_up_and_exits_1_with_one_line(
        patch_on: str, capsys: pytest.CaptureFixture[str]) -> None:
    sniff = Command(["sniff", "-i", "gone", "-c", patch_on, "--view", "none"], capsys)
    wait_until(lambda: any(t.name.startswith('Notifier for bus "faulty') and patch_on in t.name
                           for t in threading.enumerate()),  # sniff's, not the patch's
               what="skin sniff receiving", timeout=WAIT_S, interval=0.02)
    GONE.set()
    assert sniff.end() == 1, sniff.out + sniff.err
    assert _one_error_line(sniff.err).startswith(f"skin: error: receiving stopped: bus "
                                                 f"gone:{patch_on}: ")


def test_skin_sim_run_on_a_bus_gone_for_good_gives_it_up_and_exits_1_with_one_line(
        patch_on: str, capsys: pytest.CaptureFixture[str]) -> None:
    sim = Command(["sim", "run", "indenter", "--patches", "1", "-i", "gone", "-c",
                   f"{patch_on}-sim"], capsys)
    sim.wait_for("Ctrl-C stops")
    GONE.set()
    assert sim.end() == 1, sim.out + sim.err
    assert "the patches cannot be heard" in _one_error_line(sim.err)


def test_seconds_cut_a_long_scan_short(patch_on: str, tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "host.toml"
    config.write_text(f"[host]\nscan_ms = {LONGEST_SCAN_MS}\n[[patches]]\nnode_id = 1\n")
    run = Command(["run", str(config), "-i", "virtual", "-c", patch_on, "--seconds", "1"],
                  capsys)
    assert run.end() == 0, run.out + run.err  # within seconds: not the 10-minute scan
    assert run.out.splitlines()[-1].startswith("published ")
    assert "no patch answered" not in run.out  # the scan was cut short, not answered


def test_sigterm_ends_a_run_in_a_long_scan_with_its_summary(tmp_path: Path) -> None:
    """SIGTERM in a 10-minute scan: the run ends within the stop's deadline of seconds."""
    config = tmp_path / "host.toml"
    config.write_text(f'[host]\nscan_ms = {LONGEST_SCAN_MS}\n[bus]\ninterface = "virtual"\n'
                      'channel = "sigterm-scan"\n[[patches]]\nnode_id = 1\n')
    out = tmp_path / "run.json"
    process = children.spawn([sys.executable, "-m", "skin.cli", "run", str(config),
                              "--json", str(out)], cwd=ROOT,
                             env={**os.environ, "PYTHONPATH": str(ROOT)})
    # The banner: the host is starting, its scan runs.
    process.wait_for("host: 1 patch on virtual:sigterm-scan", timeout=WAIT_S)
    began = time.monotonic()
    assert process.stop(signal.SIGTERM, timeout=WAIT_S) == 0, process.output()
    print(f"\nskin run, SIGTERM in a 10-minute scan: ended after "
          f"{time.monotonic() - began:.2f} s")
    first, *_, last = process.stdout().splitlines()
    assert first.startswith("host: 1 patch on virtual:sigterm-scan"), process.output()
    assert "stopped by SIGTERM" in process.stdout() and last.startswith("published ")
    assert json.loads(out.read_text())["stopped_by"] == "SIGTERM"


def test_skin_run_with_no_bus_anywhere_names_the_three_ways_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    import can

    def broken(*args: object, **kwargs: object) -> dict[str, object]:
        raise can.CanInterfaceNotImplementedError('Unknown interface type "None"')

    monkeypatch.setattr(can.util, "load_config", broken)  # what it does with no config
    config = tmp_path / "host.toml"
    config.write_text("[[patches]]\nnode_id = 1\n")
    assert main(["run", str(config)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("skin: error: no bus: ")
    for way in ("-i IFACE", "[bus]", "python-can's configuration"):
        assert way in err
