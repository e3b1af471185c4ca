"""Recording the real thing: two patches and the host manager on a virtual bus, and
the recording replayed into a listen-only host.

One live run (module fixture): patch nodes 1 and 2 (``PatchServer``; pressed taxels, and
pillar x of patch 1's taxel 4 open for one sample, so EMCY and its reset go out) and a
``HostManager`` (SDO scan and set-up, NMT, SYNC with counter, analytic decoding, force
nodes 65 and 66 publishing), while a listener records the bus to .pcap and .log.

- The .log replayed by ``canbus.tools.replay.Replayer`` (what ``skin replay`` runs) onto a
  fresh virtual bus, as fast as possible and with its original timing, into a
  ``HostManager(listen_only=True)`` with the same config: that host follows the recorded
  SYNCs, NMT commands, heartbeats and EMCYs and gives every force frame of the live run
  (cycle, SYNC counter, complete, forces bit for bit, valid, reasons with the EMCY-masked
  taxel), though the virtual bus stamps every frame with its replay time. The same
  through the CLI: ``skin run --listen-only`` and ``skin replay`` on one channel.
- Wireshark's tshark types every frame of the .pcap as we do (NMT, SYNC, PDO, heartbeat,
  SDO, EMCY all present).
- The sniffer and the view's raw resistances, reading the recording, call complete exactly
  the samples the live host published complete (one assembly of the answers).
"""

from __future__ import annotations

import json
import re
import shutil
import threading
from dataclasses import dataclass
from pathlib import Path

import can
import can.interfaces.virtual
import numpy as np
import pytest

from canbus import codes
from canbus.device.source import ArraySource
from canbus.master.dataplane import ForceFrame
from canbus.master.host import HostManager
from canbus.master.hostconfig import HostConfig, PatchConfig
from canbus.tools.answer_reader import Answer
from canbus.tools.attribution import Attribution
from canbus.tools.pdo_dictionary import Dictionary
from canbus.tools.recorder import CandumpLogWriter, Recorder
from canbus.tools.recording import Recording
from canbus.tools.replay import Replayer
from canbus.tools.services import Service, ServiceDecoder, route
from canbus.tools.sniffer import Sniffer
from decoder.reasons import Reason
from skin.cli import main
from skin.constants import DEFAULT_CONSTANTS
from skin.tripod import resistance_from_force
from tests.canbus.virtual_channels import ctrl_c, listening, read_out
from tests.support.rigs import children
from tests.support.rigs.recorded_host import recorded_host
from tests.support.rigs.waiting import wait_until

LSB = DEFAULT_CONSTANTS.resistance_lsb_ohm
CYCLES = 12
WIRESHARK_TYPES = {Service.NMT: "NMT:", Service.SYNC: "SYNC", Service.EMCY: "EMCY",
                   Service.PDO: "PDO", Service.SDO: "Default-SDO",
                   Service.HEARTBEAT: "NMT Error Control"}
# The data plane's counters that a replay must reproduce (frames of its own channels).
PDO_STATS = ("frames_in", "late_frames", "duplicate_frames", "malformed_frames",
             "samples", "complete_samples", "incomplete_samples")


def _samples() -> np.ndarray:
    """(samples, 2 patches, 9, 3) quantised resistances: a press that grows and moves."""
    count = CYCLES + 8
    force = np.zeros((count, 2, 9, 3))
    for k in range(count):
        force[k, 0, k % 9] = (0.2, -0.1, 0.25 * (k % 5))
        force[k, 1, (2 * k) % 9] = (-0.3, 0.2, 0.5 + 0.1 * k)
    r = resistance_from_force(force, DEFAULT_CONSTANTS)
    r = codes.resistance_to_code(r, LSB).astype(np.float64) * LSB
    r[6, 0, 4, 1] = np.inf  # an open pillar for one sample: EMCY, then its reset
    return r


@dataclass
class HostRun:
    folder: Path
    frames: list[ForceFrame]
    config: HostConfig
    stats: dict[str, int]


@pytest.fixture(scope="module")
def host_run(tmp_path_factory: pytest.TempPathFactory) -> HostRun:
    folder = tmp_path_factory.mktemp("host")
    channel = "sniff-host"
    # No SYNC window (its time is the machine's): a frame is late only when it comes after
    # the next SYNC, as the recording keeps it, so every replay judges it the same way.
    config = HostConfig(patches=(PatchConfig(1), PatchConfig(2)), sync_period_ms=40.0,
                        heartbeat_ms=100, scan_ms=100)
    object.__setattr__(config, "sync_window_ms", 0.0)  # the data plane's "until the next"
    recorders = [Recorder(folder / "host.pcap"), Recorder(folder / "host.log")]
    with recorded_host(channel, config, ArraySource(_samples(), (1, 2)), recorders) as run:
        wait_until(lambda: sum(f.patch == 1 for f in run.frames) >= CYCLES, what="force frames")
    return HostRun(folder, run.frames, config, run.stats)


def _seen(host: HostManager) -> int:
    """Frames the host's data plane (the notifier's last listener) has taken."""
    stats = host.dataplane.stats
    return stats.frames_in + stats.unknown_frames + stats.bus_frames


def _key(frame: ForceFrame) -> tuple[int, int]:
    return (frame.cycle, frame.patch)


def _assert_same_forces(got: list[ForceFrame], want: list[ForceFrame]) -> None:
    """The same (cycle, patch) frames with the same counter, completeness and taxels."""
    assert sorted(map(_key, got)) == sorted(map(_key, want))
    for a, b in zip(sorted(got, key=_key), sorted(want, key=_key), strict=True):
        assert (a.patch, a.force_node, a.cycle, a.sync_counter, a.complete) == \
            (b.patch, b.force_node, b.cycle, b.sync_counter, b.complete), _key(b)
        np.testing.assert_array_equal(a.force_N, b.force_N, err_msg=str(_key(b)))
        np.testing.assert_array_equal(a.valid, b.valid, err_msg=str(_key(b)))
        np.testing.assert_array_equal(a.reason, b.reason, err_msg=str(_key(b)))
        assert a.contact is not None and b.contact is not None  # the contact summary alike
        assert a.contact.to_dict() == b.contact.to_dict(), _key(b)


def test_the_live_run_has_what_the_replay_must_reproduce(host_run: HostRun) -> None:
    live = host_run.frames
    masked = [f for f in live if f.patch == 1 and f.reason[4] == Reason.FAULTY]
    assert len(masked) == 1 and not masked[0].valid[4]  # the EMCY masked taxel 4 once
    assert sum(f.complete for f in live) >= CYCLES  # something to reproduce
    assert all(f.published for f in live if f.complete)


@pytest.mark.parametrize("realtime", [False, True], ids=["fast", "original-timing"])
def test_recording_replayed_into_a_listen_only_host_gives_the_live_forces(
        host_run: HostRun, realtime: bool, request: pytest.FixtureRequest) -> None:
    channel = f"replay-{request.node.callspec.id}"
    replayed: list[ForceFrame] = []
    with can.Bus(interface="virtual", channel=channel) as bus, \
            can.Bus(interface="virtual", channel=channel) as player:
        host = HostManager(bus, host_run.config, listen_only=True)
        host.on_forces(replayed.append)
        host.start()
        try:
            result = Replayer(player, host_run.folder / "host.log", realtime=realtime).run()
            wait_until(lambda: _seen(host) == result.frames_sent, what="the replayed frames")
        finally:
            host.stop()
    _assert_same_forces(replayed, host_run.frames)
    assert not any(f.published for f in replayed)
    stats = host.stats()
    assert {k: stats[k] for k in PDO_STATS} == {k: host_run.stats[k] for k in PDO_STATS}
    assert (stats["frames_out"], stats["sync_cycles"]) == (0, host_run.stats["sync_cycles"])


def test_skin_run_listen_only_decodes_what_skin_replay_sends(
        host_run: HostRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "host.toml"
    config.write_text("[host]\nsync_period_ms = 40.0\n[[patches]]\nnode_id = 1\n"
                      "[[patches]]\nnode_id = 2\n", encoding="utf-8")
    out = tmp_path / "run.json"
    bus = ["-i", "virtual", "-c", "cli-replay"]
    replayed: list[int] = []
    printed: list[str] = []

    def shown(text: str) -> bool:
        printed.append(capsys.readouterr().out)
        return text in "".join(printed)

    def replay() -> None:  # once skin run's bus is open, it receives every frame sent
        try:
            wait_until(lambda: listening("cli-replay"), what="skin run's bus")
            replayed.append(main(["replay", str(host_run.folder / "host.log"), "--fast",
                                  *bus]))
            wait_until(lambda: read_out("cli-replay"), what="skin run took every frame")
            wait_until(lambda: shown("patch 2: operational\n"), what="the patches' states")
        finally:
            ctrl_c()  # Ctrl-C: skin run stops, with its summary

    runner = threading.Thread(target=replay)
    runner.start()
    code = main(["run", str(config), "--listen-only", "--seconds", "600", "--json", str(out),
                 *bus])
    runner.join(60.0)
    assert (code, replayed) == (0, [0])
    printed.append(capsys.readouterr().out)
    lines = "".join(printed).splitlines()  # the two commands' lines, interleaved
    assert any(line.startswith("host (listen-only): 2 patches on ") for line in lines)
    with Recording(host_run.folder / "host.log") as recording:
        recorded = sum(1 for _ in recording)
    assert any(line.startswith(f"sent {recorded:,} frames in ") for line in lines)
    assert "patch 1: operational" in lines and lines[-1].startswith("decoded ")
    record = json.loads(out.read_text())
    live = host_run.frames
    assert record["listen_only"] is True
    # skin run judges its SYNC window on this process's receive times, which a busy machine
    # stretches: a frame the live host took may be late here, never the other way round
    # (what it decodes, exactly: skin decode's test below; the window: test_dataplane*).
    assert 0 < record["stats"]["complete_samples"] <= sum(f.complete for f in live)
    assert record["stats"]["sync_cycles"] == host_run.stats["sync_cycles"]
    assert record["stats"]["frames_out"] == 0


def test_the_sniffer_and_the_view_judge_the_live_run_s_answers_as_the_host_did(
        host_run: HostRun) -> None:
    """One assembly of the patches' answers (canbus.answers): read back from the recording,
    the sniffer and the view's raw resistances call complete exactly the samples the live
    host published complete (random recordings: test_answer_agreement.py)."""
    from skin.commands.common.known_nodes import known_nodes
    from skin.commands.view.sources import recorded_resistances

    path = host_run.folder / "host.log"
    live = {(f.patch, f.cycle): f.complete for f in host_run.frames}
    answers: list[Answer] = []
    sniffer = Sniffer(ServiceDecoder(attribution=Attribution(
        Dictionary(), known_nodes(host_run.config))), on_answer=answers.append)
    with Recording(path) as recording:
        for msg in recording:
            sniffer.on_message_received(msg)
    sniffed = {(a.node_id, a.cycle): a.complete for a in answers}
    viewed = {(s.patch, s.cycle): s.complete
              for node in (1, 2) for s in recorded_resistances(path, node, config=host_run.config)}
    complete = {key for key, whole in live.items() if whole}
    assert len(complete) >= 2 * CYCLES - 2  # the run has complete samples to agree on
    assert {key for key, whole in sniffed.items() if whole} == complete
    assert {key for key, whole in viewed.items() if whole} == complete
    assert set(viewed) == set(live)  # one sample per patch per SYNC
    last = max(cycle for _, cycle in live)
    assert set(sniffed) | {(1, last), (2, last)} == set(live)  # but the one no SYNC closed


def test_pcap_and_log_hold_the_same_frames(host_run: HostRun) -> None:
    with Recording(host_run.folder / "host.pcap") as pcap, \
            Recording(host_run.folder / "host.log") as log:
        a = [(m.arbitration_id, bytes(m.data), round(m.timestamp * 1e6)) for m in pcap]
        b = [(m.arbitration_id, bytes(m.data), round(m.timestamp * 1e6)) for m in log]
    assert a == b
    sniffer = Sniffer()
    with Recording(host_run.folder / "host.pcap") as recording:
        for msg in recording:
            sniffer.on_message_received(msg)
    snap = sniffer.snapshot()
    assert (snap.anomalies.unknown_frames, snap.anomalies.error_frames) == (0, 0)
    assert {str(s) for s in snap.by_service} == {str(s) for s in WIRESHARK_TYPES}


@pytest.mark.skipif(shutil.which("tshark") is None,
                    reason="tshark is not on PATH (CI installs it with `apt-get install tshark`)")
def test_wireshark_types_every_frame_of_the_host_run(host_run: HostRun) -> None:
    path = host_run.folder / "host.pcap"
    run = children.run(
        ["tshark", "-r", str(path), "-d", "can.subdissector,canopen", "-T", "fields",
         "-e", "_ws.col.Protocol", "-e", "canopen.node_id", "-e", "_ws.col.Info"], timeout=120)
    assert run.returncode == 0, run.stderr
    rows = [line.split("\t") for line in run.stdout.splitlines()]
    with Recording(path) as recording:
        frames = list(recording)
    assert len(rows) == len(frames)
    seen = set()
    for number, (msg, (protocol, node, info)) in enumerate(zip(frames, rows, strict=True), 1):
        where = route(msg)
        assert protocol == "CANopen", (number, info)
        assert info.startswith(WIRESHARK_TYPES[where.service]), (number, where, info)
        if where.node is not None:
            assert int(node, 0) == where.node, (number, where, node)
        seen.add(where.service)
    assert seen == set(WIRESHARK_TYPES)


def test_skin_decode_gives_what_a_listen_only_host_publishes_for_a_replay(
        host_run: HostRun, tmp_path: Path) -> None:
    """Offline, on the recording's clock: the same samples, value for value, as a listen-only
    host fed the replay, and the same every time (pcap and log alike)."""
    from canbus.offline.decode import decode_recording

    replayed: list[ForceFrame] = []
    with can.Bus(interface="virtual", channel="decode-replay") as bus, \
            can.Bus(interface="virtual", channel="decode-replay") as player:
        host = HostManager(bus, host_run.config, listen_only=True)
        host.on_forces(replayed.append)
        host.start()
        try:
            result = Replayer(player, host_run.folder / "host.log", realtime=False).run()
            wait_until(lambda: _seen(host) == result.frames_sent, what="the replayed frames")
        finally:
            host.stop()
    offline = decode_recording(host_run.folder / "host.log", host_run.config)
    _assert_same_forces(offline, replayed)
    again = decode_recording(host_run.folder / "host.pcap", host_run.config)
    _assert_same_forces(again, offline)
    out = tmp_path / "forces.npz"
    assert main(["decode", str(host_run.folder / "host.pcap"), "--config",
                 str(_write_config(tmp_path)), "-o", str(out)]) == 0
    saved = np.load(out)
    assert saved["force_N"].shape == (len(offline), 9, 3)
    np.testing.assert_array_equal(saved["force_N"], np.array([f.force_N for f in offline]))
    assert saved["complete"].tolist() == [f.complete for f in offline]
    contacts = [f.contact for f in offline]
    assert all(c is not None for c in contacts)
    np.testing.assert_array_equal(saved["cop_m"], [c.cop_m for c in contacts if c])
    np.testing.assert_array_equal(saved["contact_force_N"], [c.force_N for c in contacts if c])
    assert saved["contact_state"].tolist() == [
        sum(1 << k for k, on in enumerate((c.in_contact, c.onset, c.release, c.near_slip,
                                           c.slipping, c.slip_onset, c.partial, c.unknown))
            if on) for c in contacts if c]
    assert saved["cop_defined"].any() and saved["contact_state"].any()  # presses were there


def _write_config(folder: Path) -> Path:
    path = folder / "host.toml"
    path.write_text("[host]\nsync_period_ms = 40.0\nheartbeat_ms = 100\n[[patches]]\n"
                    "node_id = 1\n[[patches]]\nnode_id = 2\n", encoding="utf-8")
    return path


def test_skin_decode_writes_csv_and_refuses_an_unknown_output(
        host_run: HostRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = _write_config(tmp_path)
    out = tmp_path / "forces.csv"
    assert main(["decode", str(host_run.folder / "host.log"), "--config", str(config),
                 "-o", str(out)]) == 0
    lines = out.read_text().splitlines()
    assert lines[0].startswith("cycle,sync_counter,time_s,patch,force_node,taxel,fx_N")
    assert (len(lines) - 1) % 9 == 0 and "MISSING" not in lines[1]
    assert "decoded " in capsys.readouterr().out
    assert main(["decode", str(host_run.folder / "host.log"), "--config", str(config),
                 "-o", str(tmp_path / "forces.txt")]) == 1
    assert "-o: unknown output format '.txt'" in capsys.readouterr().err
    assert not (tmp_path / "forces.txt").exists()
    assert main(["decode", str(host_run.folder / "host.log"), "--config", str(config),
                 "-o", str(out), "--contact", str(tmp_path / "contact.txt")]) == 1
    assert "--contact: the contact table is a .csv file" in capsys.readouterr().err


def test_skin_decode_writes_every_sample_s_contact(host_run: HostRun, tmp_path: Path) -> None:
    from canbus.offline.decode import decode_recording

    config = _write_config(tmp_path)
    table = tmp_path / "contact.csv"
    assert main(["decode", str(host_run.folder / "host.log"), "--config", str(config),
                 "-o", str(tmp_path / "forces.npz"), "--contact", str(table)]) == 0
    frames = decode_recording(host_run.folder / "host.log", host_run.config)
    lines = table.read_text().splitlines()
    header = lines[0].split(",")
    assert header[:8] == ["cycle", "sync_counter", "time_s", "patch", "force_node", "fx_N",
                          "fy_N", "fz_N"] and header[-8:] == [
        "in_contact", "onset", "release", "near_slip", "slipping", "slip_onset", "partial",
        "unknown"]
    assert len(lines) == len(frames) + 1
    for line, frame in zip(lines[1:], frames, strict=True):
        row = dict(zip(header, line.split(","), strict=True))
        c = frame.contact
        assert c is not None
        assert (int(row["cycle"]), int(row["patch"])) == (frame.cycle, frame.patch)
        assert float(row["fz_N"]) == c.force_N[2]
        if c.cop_defined:
            assert (float(row["cop_x_m"]), float(row["cop_y_m"])) == tuple(c.cop_m)
        else:
            assert row["cop_x_m"] == row["cop_y_m"] == ""
        assert (row["in_contact"], row["onset"], row["slipping"]) == (
            str(int(c.in_contact)), str(int(c.onset)), str(int(c.slipping)))
    assert any(line.split(",")[header.index("in_contact")] == "1" for line in lines[1:])


def test_skin_decode_speaks_of_the_recording_not_of_a_live_bus(
        host_run: HostRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Patch 1 falls silent half-way (its PDOs and heartbeats cut from the recording): the
    decode says when, in seconds of the recording, and never 'lost' or 'in the last 0 s'."""
    with Recording(host_run.folder / "host.log") as recording:
        messages = list(recording)
    first, syncs = messages[0].timestamp, [m.timestamp for m in messages
                                           if m.arbitration_id == 0x80]
    cut = syncs[len(syncs) // 2]
    silent = {0x701, *(base + 1 for base in (0x180, 0x280, 0x380, 0x480, 0x200, 0x300, 0x400))}
    path = tmp_path / "silent.log"
    with path.open("w", encoding="utf-8") as handle:
        writer = CandumpLogWriter(handle)
        for msg in messages:
            if not (msg.timestamp > cut and msg.arbitration_id in silent):
                writer.on_message_received(msg)
        writer.stop()
    assert main(["decode", str(path), "--config", str(_write_config(tmp_path)), "-o",
                 str(tmp_path / "f.csv"), "--json", str(tmp_path / "d.json")]) == 0
    out, err = capsys.readouterr()
    assert "lost" not in out + err and "in the last" not in out + err
    line = next(x for x in out.splitlines() if x.startswith("patch 1: "))
    # the last silence is the cut's (a loaded machine may have left a cycle unanswered
    # before it: a silence of its own, said as such)
    start, end = map(float, re.findall(r"no answer (\d+\.\d+)-(\d+\.\d+) s", line)[-1])
    assert cut - first - 0.001 <= start < cut - first + 0.5  # from its first unanswered SYNC
    assert end >= syncs[-1] - first - 0.5  # to the recording's end
    assert "invalid taxel-samples: " in line and "MISSING " in line
    report = json.loads((tmp_path / "d.json").read_text())["by_patch"]
    assert report["2"]["silent"] == []
    gap = report["1"]["silent"][0]
    assert gap["from_s"] == pytest.approx(start, abs=0.0005)
    assert report["1"]["invalid_by_reason"]["MISSING"] >= 9 * gap["syncs"]
