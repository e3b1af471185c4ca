"""The commands when a bus is gone for good, or a stop comes at a bad moment: exit status
1 and one line within 5 s; --seconds, SIGTERM and Ctrl-C end a run whatever the host is
doing; no bus anywhere is one line naming the three ways to give one."""

from __future__ import annotations

import json
import os
import signal
import subprocess
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
from tests.canbus.test_host import press, source

ROOT = Path(__file__).resolve().parents[2]
GONE_WITHIN_S = 5.0
WAIT_S = 30.0


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
        self.code: list[int] = []
        self.thread = threading.Thread(target=lambda: self.code.append(main(argv)))
        self.thread.start()

    def read(self) -> None:
        captured = self.capsys.readouterr()
        self.out += captured.out
        self.err += captured.err

    def wait_for(self, text: str) -> None:
        deadline = time.monotonic() + WAIT_S
        while text not in self.out + self.err:
            assert time.monotonic() < deadline, f"no {text!r} in {self.out + self.err!r}"
            assert self.thread.is_alive(), self.out + self.err
            time.sleep(0.02)
            self.read()

    def end(self) -> tuple[int, float]:
        began = time.monotonic()
        self.thread.join(WAIT_S)
        assert not self.thread.is_alive(), "the command did not end"
        self.read()
        return self.code[0], time.monotonic() - began


def _one_error_line(err: str) -> str:
    assert "Traceback" not in err
    errors = [line for line in err.splitlines() if line.startswith("skin: error: ")]
    assert len(errors) == 1, err
    assert err.splitlines()[-1] == errors[0]
    return errors[0]


def test_skin_run_on_a_bus_gone_for_good_exits_1_within_5_s_with_one_line(
        patch_on: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "host.toml"
    config.write_text("[host]\nscan_ms = 100\n[[patches]]\nnode_id = 1\n")
    out = tmp_path / "run.json"
    run = Command(["run", str(config), "-i", "gone", "-c", patch_on, "--json", str(out)],
                  capsys)
    run.wait_for("patch 1: operational")
    GONE.set()  # ENETDOWN from recv, and the interface cannot be opened again
    code, took = run.end()
    print(f"\nskin run on a bus gone for good: exit {code} after {took:.2f} s")
    assert code == 1 and took < GONE_WITHIN_S, (code, took)
    line = _one_error_line(run.err)
    assert line.startswith(f"skin: error: bus default (gone:{patch_on}): gone (")
    assert line.endswith("the host cannot hear its patches")
    record = json.loads(out.read_text())  # written first: it tells what happened
    assert record["bus_gone"] is not None
    assert record["buses"]["default"]["receive"]["failed_opens"] >= 1


def test_skin_sniff_on_a_bus_gone_for_good_exits_1_within_5_s_with_one_line(
        patch_on: str, capsys: pytest.CaptureFixture[str]) -> None:
    sniff = Command(["sniff", "-i", "gone", "-c", patch_on, "--view", "none"], capsys)
    deadline = time.monotonic() + WAIT_S
    while not any(t.name.startswith('Notifier for bus "faulty') and patch_on in t.name
                  for t in threading.enumerate()):  # sniff's, not the patch's
        assert time.monotonic() < deadline, "skin sniff did not start"
        time.sleep(0.02)
    GONE.set()
    code, took = sniff.end()
    assert code == 1 and took < GONE_WITHIN_S, (code, took)
    assert _one_error_line(sniff.err).startswith(f"skin: error: receiving stopped: bus "
                                                 f"gone:{patch_on}: ")


def test_skin_sim_run_on_a_bus_gone_for_good_exits_1_within_5_s_with_one_line(
        patch_on: str, capsys: pytest.CaptureFixture[str]) -> None:
    sim = Command(["sim", "run", "indenter", "--patches", "1", "-i", "gone", "-c",
                   f"{patch_on}-sim"], capsys)
    sim.wait_for("Ctrl-C stops")
    GONE.set()
    code, took = sim.end()
    assert code == 1 and took < GONE_WITHIN_S, (code, took)
    assert "the patches cannot be heard" in _one_error_line(sim.err)


def test_seconds_cut_a_long_scan_short(patch_on: str, tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "host.toml"
    config.write_text("[host]\nscan_ms = 30000\n[[patches]]\nnode_id = 1\n")
    began = time.monotonic()
    run = Command(["run", str(config), "-i", "virtual", "-c", patch_on, "--seconds", "1"],
                  capsys)
    code, _ = run.end()
    took = time.monotonic() - began
    print(f"\nskin run --seconds 1 in a 30 s scan: ended after {took:.2f} s")
    assert code == 0 and took < 15.0  # not the scan's 30 s
    assert run.out.splitlines()[-1].startswith("published ")
    assert "no patch answered" not in run.out  # the scan was cut short, not answered


def test_sigterm_ends_a_run_in_a_long_scan_with_its_summary(tmp_path: Path) -> None:
    config = tmp_path / "host.toml"
    config.write_text('[host]\nscan_ms = 30000\n[bus]\ninterface = "virtual"\n'
                      'channel = "sigterm-scan"\n[[patches]]\nnode_id = 1\n')
    out = tmp_path / "run.json"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    process = subprocess.Popen([sys.executable, "-m", "skin.cli", "run", str(config),
                                "--json", str(out)], cwd=ROOT, env=env, text=True,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert process.stdout is not None
    first = process.stdout.readline()  # the banner: the host is starting, its scan runs
    assert first.startswith("host: 1 patch on virtual:sigterm-scan")
    began = time.monotonic()
    process.send_signal(signal.SIGTERM)
    rest, err = process.communicate(timeout=WAIT_S)
    took = time.monotonic() - began
    print(f"\nskin run, SIGTERM in a 30 s scan: ended after {took:.2f} s")
    assert took < 10.0
    assert process.returncode == 0, err
    assert "stopped by SIGTERM" in rest and rest.splitlines()[-1].startswith("published ")
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
