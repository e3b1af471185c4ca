"""`skin run CONFIG` and `skin demo` as a user runs them."""

from __future__ import annotations

import json
import os
import threading
from collections.abc import Iterator
from pathlib import Path

import canopen
import numpy as np
import pytest

from canbus.device.patch_server import PatchServer
from canbus.device.source import ArraySource
from skin.cli import main
from skin.commands.demo import demo_scene
from skin.constants import DEFAULT_CONSTANTS
from skin.tripod import resistance_from_force


@pytest.fixture
def patches(request: pytest.FixtureRequest) -> Iterator[str]:
    """Patches 1 (3-axis) and 9 (z-only) on a virtual channel; yields the channel."""
    channel = f"run-{request.node.name}"
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05
    net.connect(interface="virtual", channel=channel)
    force = np.zeros((1, 2, 9, 3))
    force[0, :, 4, 2] = 1.5
    r = resistance_from_force(force, DEFAULT_CONSTANTS)
    servers = [PatchServer(net, ArraySource(r[:, :1], (1,))),
               PatchServer(net, ArraySource(r[:, 1:, :, :1], (9,)))]
    for server in servers:
        server.start()
    yield channel
    for server in servers:
        server.stop()
    net.disconnect()


def _in_thread(argv: list[str], timeout: float = 30.0) -> int:
    code: list[int] = []
    runner = threading.Thread(target=lambda: code.append(main(argv)))
    runner.start()
    runner.join(timeout)
    assert not runner.is_alive(), f"skin {' '.join(argv)} did not stop"
    return code[0]


def test_skin_run_hosts_the_configured_patches_and_reports_the_rest(
        patches: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "host.toml"
    config.write_text("[host]\nscan_ms = 100\n[[patches]]\nnode_id = 1\n", encoding="utf-8")
    out = tmp_path / "run.json"
    argv = ["run", str(config), "-i", "virtual", "-c", patches, "--seconds", "0.5",
            "--json", str(out), "--cpu", "last"]
    assert _in_thread(argv) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("host: 1 patch on ") and "1->65" in lines[0]
    assert "node 9: a patch that is not in the config; left alone" in lines
    assert "patch 1: operational" in lines
    assert lines[-1].startswith("published ")
    record = json.loads(out.read_text())
    assert record["patches"]["1"]["state"] == "operational" and record["unknown_nodes"] == [9]
    assert record["stats"]["samples"] == record["patches"]["1"]["samples"] > 0


@pytest.mark.parametrize(("text", "expected"), [
    ("[[patches]]\nnode_id = 1\nmodel = 'gone.msgpack'\n",
     "patches[0].model: no such file"),
    ("[[patches]]\nnode_id = 1\nforce_node = 2\n[[patches]]\nnode_id = 2\n",
     "patches[1].node_id: node-ID 2 is also patches[0].force_node"),
])
def test_skin_run_refuses_a_bad_config_in_one_line(tmp_path: Path, text: str, expected: str,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "host.toml"
    config.write_text(text, encoding="utf-8")
    assert main(["run", str(config), "-i", "virtual", "-c", "never-opened"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"skin: error: {config}: {expected}") and err.count("\n") == 1


@pytest.mark.parametrize("how", ["flag", "config"])
def test_skin_run_listen_only_opens_the_bus_and_sends_nothing(
        how: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import can

    config = tmp_path / "host.toml"
    host = "[host]\nlisten_only = true\n" if how == "config" else ""
    config.write_text(host + "[[patches]]\nnode_id = 1\n", encoding="utf-8")
    out = tmp_path / "run.json"
    argv = ["run", str(config), "-i", "virtual", "-c", f"listen-{how}", "--seconds", "0.2",
            "--json", str(out)] + (["--listen-only"] if how == "flag" else [])
    with can.Bus(interface="virtual", channel=f"listen-{how}") as spy:
        assert _in_thread(argv) == 0
        assert spy.recv(timeout=0) is None  # no scan, no SYNC, no force node boot-up
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("host (listen-only): 1 patch on ")
    assert lines[1] == "patch 1: absent" and lines[-1].startswith("decoded 0 samples ")
    record = json.loads(out.read_text())
    assert record["listen_only"] is True and record["patches"]["1"]["state"] == "absent"
    assert record["stats"]["frames_out"] == record["stats"]["sync_cycles"] == 0


def test_skin_run_listen_only_flag_is_off_by_default_and_still_checks_the_config(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from skin.cli import build_parser

    parser = build_parser()
    assert not parser.parse_args(["run", "host.toml"]).listen_only
    assert parser.parse_args(["run", "host.toml", "--listen-only"]).listen_only
    config = tmp_path / "host.toml"
    config.write_text("[host]\nlisten_only = 1\n[[patches]]\nnode_id = 1\n", encoding="utf-8")
    assert main(["run", str(config), "--listen-only", "-i", "virtual", "-c", "never"]) == 1
    err = capsys.readouterr().err
    assert err == (f"skin: error: {config}: host.listen_only: must be true or false, got an "
                   "integer 1\n")


def test_skin_run_names_a_bus_it_cannot_open(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "host.toml"
    config.write_text("[[patches]]\nnode_id = 1\n", encoding="utf-8")
    assert main(["run", str(config), "-i", "socketcan", "-c", "no-such-can9"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("skin: error: cannot open the bus socketcan:no-such-can9: ")
    assert err.count("\n") == 1


def test_skin_demo_reports_every_figure(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    """The timed bus by default: the wire's time is part of every figure."""
    out = tmp_path / "demo.json"
    assert _in_thread(["demo", "--patches", "2", "--seconds", "1.0", "--json", str(out)]) == 0
    record = json.loads(out.read_text())
    assert record["patches"] == 2 and record["decoder"] == "analytic"
    assert (record["bus"], record["bitrate"], record["fd"], record["buses"]) == \
        ("timed", 1_000_000, False, 1)
    assert record["seconds"] >= 1.0 and record["samples"] > 0
    assert record["samples"] == record["complete_samples"] + record["incomplete_samples"]
    assert isinstance(record["dropped_frames"], int) and record["dropped_frames"] >= 0
    assert record["samples_per_s"] > 0
    assert 0 < record["wire_ms"]["p50"] <= record["latency_ms"]["p50"] <= \
        record["latency_ms"]["p99"] <= record["latency_ms"]["max"]
    # The planner counts what crosses the wire; at the SYNC rate the machine kept up with.
    plan, kept = record["plan"]["load_pct"], record["sync_hz"] / record["rate_hz"]
    assert 0.9 * plan["best"] * kept <= record["bus_load_pct"] <= plan["worst"]
    assert 0 < record["rmse_N"] < 0.2  # the indenter, 3-axis, exact inverse: crosstalk only
    text = capsys.readouterr().out
    assert "skin demo: 2 patches (indenter, xyz, analytic) at 100 Hz, timed CAN" in text
    assert "rmse" in text and "measured (plan: " in text
    assert record["cpus"] is None  # the timed bus's threads roam


def test_skin_demo_on_the_virtual_bus_pins_one_cpu(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "demo.json"
    assert _in_thread(["demo", "--bus", "virtual", "--patches", "2", "--seconds", "0.5",
                       "--json", str(out)]) == 0
    record = json.loads(out.read_text())
    assert record["bus"] == "virtual" and record["bus_load_pct"] is None
    assert record["wire_ms"] == {"p50": None, "p99": None}
    assert 0 < record["latency_ms"]["p50"] <= record["latency_ms"]["p99"]
    text = capsys.readouterr().out
    if hasattr(os, "sched_getaffinity"):  # by default every thread on the last CPU
        last = max(os.sched_getaffinity(0))
        assert record["cpus"] == [last] and f", CPU {last}\n" in text


@pytest.mark.parametrize("flags", [["--fd"], ["--buses", "2"]], ids=["fd", "two-buses"])
def test_skin_demo_fd_and_several_buses(tmp_path: Path, flags: list[str]) -> None:
    out = tmp_path / "demo.json"
    assert _in_thread(["demo", "--patches", "2", "--seconds", "1.0", *flags,
                       "--json", str(out)]) == 0
    record = json.loads(out.read_text())
    assert record["samples"] > 0 and record["fd"] == ("--fd" in flags)
    assert record["buses"] == (2 if "--buses" in flags else 1)
    kept = record["sync_hz"] / record["rate_hz"]
    for name, load in record["bus_loads_pct"].items():
        planned = record["plan"]["buses"][name]
        assert 0.9 * planned["best"] * kept <= load <= planned["worst"], name
    assert record["wire_ms"]["p50"] <= record["latency_ms"]["p50"]


def test_skin_demo_refuses_traffic_the_bus_cannot_carry(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert _in_thread(["demo", "--patches", "8", "--seconds", "0.5"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("skin: error: --patches: 8 patches x 100 Hz (xyz)") and \
        "133-162 % load" in err and "cannot fit; use --fd, --buses 2" in err  # contact PDO in


def test_skin_demo_refuses_a_cpu_it_cannot_use(capsys: pytest.CaptureFixture[str]) -> None:
    assert _in_thread(["demo", "--seconds", "0.5", "--cpu", "4096"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("skin: error: --cpu: ") and err.count("\n") == 1


def test_skin_demo_defaults_end_by_themselves(capsys: pytest.CaptureFixture[str]) -> None:
    from skin.cli import build_parser

    args = build_parser().parse_args(["demo"])  # the README's line: a few seconds, exit 0
    assert (args.patches, args.seconds, args.scene, args.json) == (4, 3.0, "indenter", None)
    assert _in_thread(["demo", "--seconds", "0.5", "--scene", "paper"]) == 0
    text = capsys.readouterr().out
    assert "skin demo: 4 patches (paper, z, analytic)" in text


def test_demo_scenes_put_every_load_on_every_patch() -> None:
    hard = demo_scene("hard", 3)
    assert hard.node_ids == (1, 2, 3)
    assert all(load.patches == (1, 2, 3) for load in hard.loads)
    faults = hard.effects["faults"].pillars
    assert {f.node_id for f in faults} == {1, 2}  # faults of patches that still exist
    assert demo_scene("indenter", None) is not None and demo_scene("indenter", 1).node_ids == (1,)


def test_skin_demo_on_a_terminal_shows_the_skin_live(capsys: pytest.CaptureFixture[str],
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    import sys

    monkeypatch.setattr(sys.stdout, "isatty", lambda: True)
    assert _in_thread(["demo", "--patches", "1", "--seconds", "0.6"]) == 0
    text = capsys.readouterr().out
    # skin view's live heat map: the patch, its state, rate and completeness, its taxels
    assert "skin demo (indenter)" in text and "patch 1" in text and "live" in text
    assert "complete" in text and "max Fz" in text and "rmse" in text


def test_skin_run_with_no_bus_anywhere_says_so_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    import can

    monkeypatch.setattr(can.util, "load_config", lambda *a, **k: {})
    config = tmp_path / "host.toml"
    config.write_text("[[patches]]\nnode_id = 1\n")
    assert main(["run", str(config)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("skin: error: no bus: ") and err.count("\n") == 1
    assert "-i socketcan -c can0" in err


def test_skin_run_takes_its_bus_from_the_config_and_finds_the_config(
        patches: str, tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    config = tmp_path / "host.toml"
    config.write_text(f'[bus]\ninterface = "virtual"\nchannel = "{patches}"\n'
                      "[[patches]]\nnode_id = 1\n")
    monkeypatch.setenv("SKIN_HOST_CONFIG", str(config))  # no CONFIG argument: found there
    out = tmp_path / "run.json"
    assert _in_thread(["run", "--seconds", "1.0", "--status-every", "0.4", "--json",
                       str(out)]) == 0
    text = capsys.readouterr().out
    assert "patch 1: operational" in text and "status: 1/1 patches operational" in text
    record = json.loads(out.read_text())
    assert record["stats"]["complete_samples"] > 0
    assert record["buses"]["default"]["patches"] == [1]
    # the steady state is told apart from the set-up, in the summary and the figures
    stats = record["stats"]
    assert 0 < stats["steady_complete_samples"] <= stats["steady_samples"] <= stats["samples"]
    assert record["steady_complete_pct"] == round(
        100 * stats["steady_complete_samples"] / stats["steady_samples"], 3)
    setup = stats["samples"] - stats["steady_samples"]
    assert f"{setup} samples during set-up" in text
    assert f"steady state (every patch operational): {stats['steady_samples']} samples" in text


def test_skin_run_refuses_bus_flags_for_a_config_of_several_buses(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "host.toml"
    config.write_text('[[buses]]\nname = "a"\ninterface = "virtual"\n[[buses]]\nname = "b"\n'
                      'interface = "virtual"\n[[patches]]\nnode_id = 1\nbus = "a"\n')
    assert main(["run", str(config), "-i", "virtual"]) == 1
    assert "has 2 buses ([[buses]]): set each one in its table" in capsys.readouterr().err
