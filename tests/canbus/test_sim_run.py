from __future__ import annotations

import json
import queue
import time
from collections.abc import Callable
from pathlib import Path

import can
import canopen
import pytest

from canbus.od import load_od
from skin.cli import main
from tests.canbus.virtual_channels import run_until_done

SECONDS = 0.6


def test_sim_run_stops_when_its_time_is_up(request: pytest.FixtureRequest,
                                          tmp_path: Path) -> None:
    out = tmp_path / "run.json"
    started = time.monotonic()
    assert main(["sim", "run", "indenter", "--seconds", str(SECONDS), "-i", "virtual", "-c",
                 f"sim-run-{request.node.name}", "--json", str(out)]) == 0
    wall = time.monotonic() - started
    record = json.loads(out.read_text())
    assert record["stopped_by"] is None and record["syncs"] == 0
    assert SECONDS <= record["seconds"] < wall  # any machine: within the call, never short


def test_sim_run_serves_the_scene(request: pytest.FixtureRequest, tmp_path: Path) -> None:
    channel = f"sim-run-{request.node.name}"
    master = canopen.Network()
    master.NOTIFIER_CYCLE = 0.05
    master.connect(interface="virtual", channel=channel)
    raw = can.Bus(interface="virtual", channel=channel)
    frames: queue.Queue[can.Message] = queue.Queue()
    notifier = can.Notifier(raw, [frames.put], timeout=0.05)
    out = tmp_path / "run.json"
    seen: list[can.Message] = []

    def until(condition: Callable[[list[can.Message]], bool]) -> None:
        while not condition(seen):
            seen.append(frames.get(timeout=30.0))

    def traffic() -> None:
        until(lambda got: bool(got))
        assert (seen[0].arbitration_id, bytes(seen[0].data)) == (0x701, b"\x00")  # boot-up
        node = master.add_node(canopen.RemoteNode(1, load_od("skin-patch", 1)))
        node.sdo.RESPONSE_TIMEOUT = 2.0
        node.sdo[0x1017].raw = 50
        node.nmt.send_command(0x01)
        until(lambda got: any(m.arbitration_id == 0x701 and m.data == b"\x05" for m in got))
        master.sync.transmit()
        until(lambda got: sum(0x180 <= m.arbitration_id < 0x580 for m in got) == 7)

    try:
        code = run_until_done(["sim", "run", "indenter", "-i", "virtual", "-c", channel,
                               "--json", str(out)], traffic)
    finally:
        notifier.stop(timeout=1.0)
        raw.shutdown()
        master.disconnect()
    while not frames.empty():
        seen.append(frames.get_nowait())
    assert code == 0
    beats = [bytes(m.data) for m in seen[1:] if m.arbitration_id == 0x701]
    assert len(beats) >= 2 and set(beats) <= {b"\x7f", b"\x05"} and beats[-1] == b"\x05"
    tpdos = sorted(m.arbitration_id for m in seen if 0x180 <= m.arbitration_id < 0x580)
    assert tpdos == [0x181, 0x201, 0x281, 0x301, 0x381, 0x401, 0x481]  # 27 values, 7 TPDOs
    record = json.loads(out.read_text())
    assert record["syncs"] == 1 and record["frames"] == 7 and record["stopped_by"] == "SIGINT"


def test_sim_run_spreads_the_patches_over_buses_each_answering_its_sync(
        request: pytest.FixtureRequest, tmp_path: Path) -> None:
    """--patches 5 --buses 2 on virtual: channels CHANNEL0 and CHANNEL1, patches 1-3 and
    4-5, each bus's SYNC answered by its own patches only, in COB-ID then node-ID order."""
    channel = f"sim-buses-{request.node.name}"
    raws = [can.Bus(interface="virtual", channel=f"{channel}{k}", receive_own_messages=True)
            for k in range(2)]
    queues: list[queue.Queue[can.Message]] = [queue.Queue(), queue.Queue()]
    notifiers = [can.Notifier(raw, [q.put], timeout=0.05) for raw, q in zip(raws, queues,
                                                                              strict=True)]
    out = tmp_path / "run.json"
    seen: list[list[int]] = [[], []]

    def traffic() -> None:
        for q, count in zip(queues, (3, 2), strict=True):  # the boot-ups
            assert sorted(q.get(timeout=30.0).arbitration_id for _ in range(count))[0] == \
                (0x701 if count == 3 else 0x704)
        for raw in raws:  # NMT start, then SYNC: the patches take them in that order
            raw.send(can.Message(arbitration_id=0, data=[1, 0], is_extended_id=False))
            raw.send(can.Message(arbitration_id=0x080, data=[1], is_extended_id=False))
        for k, count in enumerate((21, 14)):  # NMT and SYNC (own messages), the TPDOs
            while sum(0x180 <= c < 0x500 for c in seen[k]) < count:
                seen[k].append(queues[k].get(timeout=30.0).arbitration_id)

    try:
        code = run_until_done(["sim", "run", "indenter", "--patches", "5", "--buses", "2",
                               "-i", "virtual", "-c", channel, "--json", str(out)], traffic)
    finally:
        for notifier, raw in zip(notifiers, raws, strict=True):
            notifier.stop(timeout=1.0)
            raw.shutdown()
    assert code == 0
    for k, (q, nodes) in enumerate(zip(queues, ([1, 2, 3], [4, 5]), strict=True)):
        got = seen[k] + _drain(q)
        after_sync = got[got.index(0x080) + 1:]
        tpdos = [c for c in after_sync if 0x180 <= c < 0x500]
        assert tpdos == [base + n for n in nodes for base in
                         (0x180, 0x200, 0x280, 0x300, 0x380, 0x400, 0x480)]
    record = json.loads(out.read_text())
    assert [b["nodes"] for b in record["buses"]] == [[1, 2, 3], [4, 5]]
    assert record["syncs"] == 2 and record["frames"] == 35


def _drain(q: queue.Queue[can.Message]) -> list[int]:
    out = []
    while not q.empty():
        out.append(q.get_nowait().arbitration_id)
    return out


def test_sim_run_warns_when_one_bus_cannot_carry_the_skin(capsys: pytest.CaptureFixture[str],
                                                         request: pytest.FixtureRequest) -> None:
    channel = f"sim-plan-{request.node.name}"
    assert main(["sim", "run", "skin64-xyz", "--seconds", "0.01", "-i", "virtual", "-c",
                 channel]) == 0
    err = capsys.readouterr().err
    assert "warning: 1 bus of CAN 1,000,000 bit/s cannot carry 64 patches x 100 Hz (xyz)" in err
    assert "use --buses" in err and "(skin plan)" in err
    assert main(["sim", "run", "indenter", "--patches", "2", "--seconds", "0.01", "-i",
                 "virtual", "-c", channel]) == 0
    assert "warning" not in capsys.readouterr().err


@pytest.mark.parametrize(("argv", "message"), [
    (["--buses", "3"], "--buses: must be in 1..1"),
    (["--patches", "0"], "argument --patches: must be in 1..127"),
    (["--patches", "4", "--buses", "2", "-c", "a,b,c"], "--channel: 3 channels for --buses 2"),
    (["--patches", "2", "--buses", "2", "-i", "socketcan", "-c", "can0"],
     "--buses: name the 2 channels of socketcan"),
    (["--patches", "2", "--buses", "2", "--truth", "never-written.csv"],
     "--truth: writes one bus's answers: use it with --buses 1"),
])
def test_sim_run_refuses_bad_buses_in_one_line(argv: list[str], message: str,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    try:
        status = main(["sim", "run", "indenter", "--seconds", "0.01", "-i", "virtual", *argv])
    except SystemExit as usage:  # a value out of its range: argparse's own one line
        status = 1 if usage.code == 2 else 0
    assert status == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not Path("never-written.csv").exists()


@pytest.mark.parametrize(("interface", "warned"), [("virtual", False), ("udp_multicast", False),
                                                   ("timed", True)])
def test_the_planner_warns_of_a_target_only_where_there_is_a_wire(
        interface: str, warned: bool, capsys: pytest.CaptureFixture[str],
        udp_channel: str, udp_port: int) -> None:
    """The idle scene's four patches at 100 Hz with their force PDOs: 62-76 % of a classic
    1 Mbit/s wire, above the 70 % target, which is a margin for a wire's worst case."""
    bus = ["-i", interface, "-c", udp_channel if interface == "udp_multicast" else "tight"]
    if interface == "udp_multicast":
        bus += ["--bus-kwargs", f"port={udp_port}"]
    assert main(["sim", "run", "idle", "--seconds", "0.01", *bus]) == 0
    err = capsys.readouterr().err
    assert ("is above the 70 % target" in err) == warned
    assert "cannot carry" not in err


def test_sim_run_whose_simulator_fails_ends_with_one_line_and_its_json(
        request: pytest.FixtureRequest, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A simulator that raises mid-run does not leave the patches answering with a frozen
    sample for ever: the run ends, exit status 1, one line naming the error, --json says so."""
    from canbus.device.source import SimulatorSource

    real = SimulatorSource.read
    reads = [0]

    def failing(self: SimulatorSource) -> object:
        reads[0] += 1
        if reads[0] > 5:
            raise FloatingPointError("the contact solve diverged")
        return real(self)

    monkeypatch.setattr(SimulatorSource, "read", failing)
    out = tmp_path / "run.json"
    code = main(["sim", "run", "indenter", "-i", "virtual", "-c", f"fail-{request.node.name}",
                 "--seconds", "60", "--json", str(out)])
    assert code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == ("skin: error: the simulator failed (FloatingPointError: the contact "
                       "solve diverged): the patches sent EMCY 0x6100 and stopped answering")
    record = json.loads(out.read_text())
    assert record["source_failed"] == "FloatingPointError('the contact solve diverged')"
    assert record["seconds"] < 60
