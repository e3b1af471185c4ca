"""One set of bus defaults for every command: the flags, else the host config's [bus], else
python-can's configuration; no silent bus inside the process; the bus said, virtual warned."""

from __future__ import annotations

import argparse
import threading
from pathlib import Path

import pytest

from skin.cli import main
from skin.commands.common.busopen import choose_bus


@pytest.fixture(autouse=True)
def _no_python_can_config(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    for name in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_BITRATE", "CAN_CONFIG"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))  # no ~/.canrc
    monkeypatch.chdir(tmp_path)  # no ./can.ini


@pytest.mark.parametrize("argv", [["sniff", "--seconds", "0.1"], ["tare", "65"],
                                  ["replay", "--fast", "REC"], ["view", "--seconds", "0.1"],
                                  ["sim", "run", "idle", "--seconds", "0.1"]])
def test_no_bus_anywhere_is_one_line_not_an_empty_bus(argv: list[str], tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    rec = tmp_path / "r.log"
    rec.write_text("(1.000000) can0 080#01\n", encoding="utf-8")
    argv = [str(rec) if a == "REC" else a for a in argv]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"skin: error: skin {argv[0]}") and ": no bus: give -i IFACE" in err
    assert "python-can's configuration" in err and err.count("\n") == 1


GROUP = "239.74.1.9"  # no socket: a channel name the bus choice reports, never opened
OTHER_GROUP = "239.74.1.10"  # no socket: as GROUP
DEFAULT_GROUP = "239.74.163.2"  # no socket: canskin's default channel, as the config names it

def test_python_can_s_configuration_is_a_default(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CAN_INTERFACE", "udp_multicast")
    monkeypatch.setenv("CAN_CHANNEL", GROUP)
    args = argparse.Namespace()
    assert choose_bus(args, command="skin sniff") == \
        f"udp_multicast:{GROUP} (from python-can's configuration)"
    given = argparse.Namespace(interface="udp_multicast")  # -i, and the config's channel
    assert choose_bus(given, command="x") == f"udp_multicast:{GROUP} (from -i)"
    other = argparse.Namespace(interface="virtual")  # another interface: canskin's channel
    assert choose_bus(other, command="x") == "virtual:skin (from -i)"


def test_a_host_config_s_bus_is_a_default(tmp_path: Path) -> None:
    from canbus.master.hostconfig import load_host_config

    path = tmp_path / "h.toml"
    path.write_text('[bus]\ninterface = "virtual"\nchannel = "cfg-bus"\nbitrate = 500000\n'
                    "[[patches]]\nnode_id = 1\n", encoding="utf-8")
    args = argparse.Namespace()
    assert choose_bus(args, command="x", config=load_host_config(path)) == \
        f"virtual:cfg-bus (from {path} [bus])"
    assert args.bitrate == 500_000


def test_sniff_and_tare_say_which_bus_and_that_virtual_is_theirs_alone(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sniff", "-i", "virtual", "-c", "said", "--seconds", "0.1", "--view",
                 "none"]) == 0
    captured = capsys.readouterr()
    first = captured.out.splitlines()[0]  # --view none: stdout is the summary
    assert first.startswith("skin sniff: bus virtual:said (from -i); note: virtual is a bus "
                            "inside this process: it hears nothing of another process")
    assert captured.err == ""  # an error after it would be the one line on stderr

    ready, done = threading.Event(), threading.Event()

    def answer() -> None:  # a force node that takes the tare
        import canopen

        from canbus.master.forcenode import ForceNode

        net = canopen.Network()
        net.NOTIFIER_CYCLE = 0.05
        net.connect(interface="virtual", channel="said-tare")
        node = ForceNode(65, 1)
        node.on_tare = lambda: None
        node.attach(net)
        ready.set()
        done.wait(30.0)
        net.disconnect()

    worker = threading.Thread(target=answer)
    worker.start()
    try:
        assert ready.wait(30.0)
        assert main(["tare", "65", "-i", "virtual", "-c", "said-tare"]) == 0
    finally:
        done.set()
        worker.join()
    captured = capsys.readouterr()
    said, result = captured.out.splitlines()
    assert said.startswith("skin tare: bus virtual:said-tare (from -i); note: virtual is a bus "
                           "inside this process: it sends to and hears nothing of another "
                           "process")
    assert result == "force node 65: tared"


def test_skin_run_takes_the_same_channel_default(monkeypatch: pytest.MonkeyPatch,
                                                 tmp_path: Path) -> None:
    from canbus.master.hostconfig import load_host_config
    from skin.commands.common.hostbus import resolve

    path = tmp_path / "h.toml"
    path.write_text("[[patches]]\nnode_id = 1\n", encoding="utf-8")
    monkeypatch.setenv("CAN_CHANNEL", OTHER_GROUP)
    config = resolve(load_host_config(path), argparse.Namespace(interface="udp_multicast"))
    assert (config.buses[0].interface, config.buses[0].channel) == ("udp_multicast", OTHER_GROUP)
    monkeypatch.delenv("CAN_CHANNEL")
    config = resolve(load_host_config(path), argparse.Namespace(interface="udp_multicast"))
    assert config.buses[0].channel == DEFAULT_GROUP
