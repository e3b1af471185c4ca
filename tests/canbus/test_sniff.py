"""The sniffer: anomaly counters and bus load on scripted traces; `skin sniff` on live traffic.

The live capture: two patch nodes (``PatchServer``, one taxel of patch 1 open for one
sample, so an EMCY and its reset go out) and a canopen master (SDO read and write, NMT
start, SYNC with counter) on a virtual bus, with ``skin sniff --view lines --record
F.pcap --json`` listening; the traffic thread ends the sniffer with a simulated Ctrl-C.
"""

from __future__ import annotations

import contextlib
import json
import re
import shutil
import threading
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import can
import can.cli
import canopen
import numpy as np
import pytest
from rich.console import Console

from canbus.device.nmt_slave import OPERATIONAL
from canbus.device.patch_server import PatchServer
from canbus.frametime import classic_frame_bits, frame_bit_bounds
from canbus.od import load_od
from canbus.tools.answer_reader import Answer
from canbus.tools.attribution import Attribution, KnownNode
from canbus.tools.pdo_dictionary import Dictionary
from canbus.tools.recording import Recording
from canbus.tools.services import Service, ServiceDecoder, route
from canbus.tools.sniffer import FrameFilter, Sniffer
from skin.cli import main
from skin.commands.common import busopen
from skin.commands.sniff.view import ViewStats, render
from skin.constants import DEFAULT_CONSTANTS
from tests.canbus.virtual_channels import ctrl_c, listening, read_out
from tests.support.rigs import children
from tests.support.rigs.waiting import wait_until

SYNCS = 6
CYCLE_S = 0.05


def _msg(t: float, cob_id: int, data: bytes = b"", **kw: object) -> can.Message:
    return can.Message(timestamp=t, arbitration_id=cob_id, data=data,
                       is_extended_id=bool(kw.pop("extended", False)), **kw)  # type: ignore[arg-type]


PATCH_ANSWER = (0x181, 0x201, 0x281, 0x301, 0x381, 0x401, 0x481)  # patch 1, as it sends one
FORCE_NODE = 65  # TPDO 1, 2 at 0x1C1, 0x2C1


def _answer(node: int, cycle: int, *, lose: int | None = None) -> list[tuple[int, bytes]]:
    """Patch ``node``'s answer to SYNC ``cycle``: its 7 TPDOs in sending order, codes that
    name the cycle; ``lose``: the COB-ID of patch 1's TPDO that does not come."""
    return [(cob - 1 + node, bytes([cycle, node, k, 0, 0, 0, 0, 0]))
            for k, cob in enumerate(PATCH_ANSWER) if cob != lose]


def _sync_trace() -> list[can.Message]:
    """SYNC 1, 2, 3, 5, 6 (4 missed). Patch 1: whole; whole with a frame retransmitted
    (the same bytes again); TPDO 4 (0x301) lost; TPDO 2 again with other bytes. Patch 2:
    whole, silent, whole, whole. Force node 65 (no patch: judged by the PDOs it sends in
    other cycles): TPDO 1 and 2; TPDO 1 alone; TPDO 2 twice; nothing."""
    frames = [_msg(-0.001, 0x181, bytes(8))]  # before the first SYNC: not judged
    repeated = _answer(1, 2)
    repeated.insert(3, repeated[2])
    doubled = _answer(1, 5)
    doubled.insert(2, (0x201, bytes(8)))
    cycles = {1: _answer(1, 1) + _answer(2, 1) + [(0x1C1, bytes(8)), (0x2C1, bytes(8))],
              2: [*repeated, (0x1C1, bytes(8))],
              3: _answer(1, 3, lose=0x301) + _answer(2, 3)
              + [(0x1C1, bytes(8)), (0x2C1, bytes(8)), (0x2C1, bytes(8))],
              5: doubled + _answer(2, 5), 6: _answer(1, 6)}
    for counter, t in zip((1, 2, 3, 5, 6), (0.0, 0.01, 0.02, 0.04, 0.05), strict=True):
        frames.append(_msg(t, 0x080, bytes([counter])))
        frames += [_msg(t + 0.0001 * (k + 1), c, d) for k, (c, d) in enumerate(cycles[counter])]
    frames += [_msg(0.1 * k, 0x701, b"\x05") for k in (1, 2, 3, 5, 6)]  # a 200 ms gap
    frames += [_msg(0.7, 0x123, b"\x01"), _msg(0.71, 0x123, b"\x02"),
               _msg(0.72, 0x1ABCDE, b"\x00", extended=True), _msg(0.73, 0x501, bytes(8)),
               can.Message(timestamp=0.74, is_error_frame=True)]
    return sorted(frames, key=lambda m: m.timestamp)


def _told(*patches: int) -> ServiceDecoder:
    """A decoder told (as a host config tells it) that ``patches`` and force node 65 keep
    their defaults."""
    return ServiceDecoder(attribution=Attribution(
        Dictionary(), [*(KnownNode(n, "skin-patch") for n in patches),
                       KnownNode(FORCE_NODE, "skin-forces")]))


def test_anomalies_on_a_scripted_trace() -> None:
    answers: list[Answer] = []
    sniffer = Sniffer(_told(1, 2), on_answer=answers.append)
    for msg in _sync_trace():
        sniffer.on_message_received(msg)
    snap = sniffer.snapshot()
    a = snap.anomalies
    # patches as the host judges them (canbus.answers), cycle by cycle: patch 1 complete in
    # 1, 2 (a retransmission changes nothing) and 5 (whole: at once, its cycle still open),
    # patch 2 in 1, 3 and 4 (SYNC 5); its silent cycle is a sample, incomplete
    assert [(x.node_id, x.cycle, x.sync_counter, x.complete) for x in answers] == [
        (1, 1, 1, True), (2, 1, 1, True), (1, 2, 2, True), (2, 2, 2, False),
        (2, 3, 3, True), (1, 3, 3, False), (2, 4, 5, True), (1, 4, 5, False),
        (1, 5, 6, True)]
    # the force node: complete in its first cycle, short in the second, doubled in the third
    assert (a.missed_sync, a.incomplete_samples, a.complete_samples) == (1, 3 + 2, 6 + 1)
    assert a.heartbeat_gaps == 1
    assert (a.unknown_frames, a.unknown_cob_ids, a.error_frames) == (3, (0x123, 0x1ABCDE), 1)
    assert (a.unattributed_frames, a.unattributed_cob_ids) == (1, (0x501,))  # no such PDO
    sync = next(r for r in snap.rows if r.cob_id == 0x080)
    assert sync.count == 5
    assert (sync.dt_min_s, sync.dt_max_s) == pytest.approx((0.01, 0.02))
    assert sync.rate_hz == pytest.approx(4 / 0.05)
    json.dumps(snap.to_dict(1.0))  # the --json summary is plain JSON


def test_missed_syncs_by_counter_wrap_and_by_time() -> None:
    counted = Sniffer()
    for k, counter in enumerate((238, 239, 240, 1, 2, 239, 3)):
        counted.on_message_received(_msg(0.01 * k, 0x080, bytes([counter])))
    # 240 -> 1 wraps cleanly; 2 -> 239 skips 236; 239 -> 3 (top 240) skips 240, 1, 2
    assert counted.snapshot().anomalies.missed_sync == 236 + 3
    timed = Sniffer()
    for t in (0.0, 0.01, 0.02, 0.03, 0.06, 0.07, 0.08):
        timed.on_message_received(_msg(t, 0x080))
    assert timed.snapshot().anomalies.missed_sync == 2


def test_bus_load_counts_bits_as_skin_plan() -> None:
    sniffer = Sniffer(bitrate=500_000)
    frames = [_msg(0.0, 0x181, bytes(8)), _msg(0.5, 0x701, b"\x05"),
              _msg(1.0, 0x123, is_remote_frame=True, dlc=8),
              _msg(1.0, 0x1ABCDE, bytes(8), extended=True)]
    for msg in frames:
        sniffer.on_message_received(msg)
    snap = sniffer.snapshot()
    # 29-bit id, 8 bytes: 54 + 64 = 118 stuffed bits (+29 worst-case stuff) + 13 = 131 / 160
    assert frame_bit_bounds(frames[3], 500_000, None) == (131.0, 160.0)
    best = classic_frame_bits(8, worst_case_stuffing=False) + \
        classic_frame_bits(1, worst_case_stuffing=False) + \
        classic_frame_bits(0, worst_case_stuffing=False) + 131
    assert snap.bits_best == best
    assert snap.load_pct(2.0)[0] == pytest.approx(100 * best / (500_000 * 2.0))


@dataclass
class Capture:
    folder: Path
    code: int
    lines: list[str]
    summary: str
    sent: list[can.Message]  # what a plain listener on the same bus saw
    record: dict[str, object]


def _samples() -> np.ndarray:
    r0 = DEFAULT_CONSTANTS.nominal_resistance_ohm
    samples = np.tile(r0, (SYNCS + 2, 2, 9, 1))
    samples[3, 0, 4, 1] = np.inf  # pillar x of taxel 4 of patch 1 opens for one sample
    return samples


def _network(channel: str) -> canopen.Network:
    net = canopen.Network()
    net.NOTIFIER_CYCLE = CYCLE_S
    return net.connect(interface="virtual", channel=channel)


def _traffic(channel: str, seen: list[can.Message], failures: list[BaseException]) -> None:
    from canbus.device.source import ArraySource

    try:
        wait_until(lambda: listening(channel), what="skin sniff listening")
        listen = can.Bus(interface="virtual", channel=channel)
        device, master = _network(channel), _network(channel)
        try:
            with PatchServer(device, ArraySource(_samples(), (1, 2))) as server:
                node = master.add_node(canopen.RemoteNode(1, load_od("skin-patch", 1)))
                node.sdo.RESPONSE_TIMEOUT = 2.0
                assert node.sdo[0x1018][2].raw == 1
                node.sdo[0x1017].raw = 100
                master.nmt.state = "OPERATIONAL"
                wait_until(lambda: all(n.state == OPERATIONAL for n in server.nodes),
                           what="both patches operational")
                for counter in range(1, SYNCS + 1):
                    sent = server.frames_sent
                    master.send_message(0x080, bytes([counter]))
                    wait_until(lambda: server.frames_sent == sent + 14,  # noqa: B023
                               what=f"the answers to SYNC {counter}")
                wait_until(lambda: read_out(channel, listen, device.bus, master.bus),
                           what="skin sniff received every frame")
        finally:
            master.disconnect()
            device.disconnect()
            while (msg := listen.recv(0)) is not None:
                seen.append(msg)
            listen.shutdown()
    except BaseException as err:
        failures.append(err)
    finally:
        ctrl_c()  # Ctrl-C: the sniffer ends, keeping what it recorded


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Capture:
    folder = tmp_path_factory.mktemp("sniff")
    seen: list[can.Message] = []
    failures: list[BaseException] = []
    channel = "sniff-live"
    worker = threading.Thread(target=_traffic, args=(channel, seen, failures))
    out, err = folder / "stdout", folder / "stderr"
    with out.open("w") as stdout, err.open("w") as stderr, \
            contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        worker.start()
        code = main(["sniff", "-i", "virtual", "-c", channel, "--view", "lines",
                     "--seconds", "30",
                     "--record", str(folder / "live.pcap"), "--json", str(folder / "s.json")])
    worker.join(timeout=30)
    if failures:
        raise failures[0]
    return Capture(folder, code, out.read_text().splitlines(), err.read_text(), seen,
                   json.loads((folder / "s.json").read_text()))


def test_sniff_shows_every_service(capture: Capture) -> None:
    assert capture.code == 0
    assert len(capture.lines) == len(capture.sent)
    services = {re.match(r"\S+ \S+ \[\d\] .{23} (\S+)", line).group(1)  # type: ignore[union-attr]
                for line in capture.lines}
    assert services == {"nmt", "sync", "emcy", "pdo", "sdo", "heartbeat"}
    text = "\n".join(capture.lines)
    for expected in ["read 0x1018:02 Identity object.Product code",
                     "0x1018:02 Identity object.Product code = 0x00000001",
                     "write 0x1017:00 Producer heartbeat time = 100 ms",
                     "write 0x1017:00 Producer heartbeat time done", "start all nodes",
                     "SYNC counter 6", "(taxel 4: x open)", "(taxel 4: ok)",
                     "patch 1    TPDO4     R4z=1000.00 Ω R4x=open R4y=1414.20 Ω R5z=1000.00 Ω",
                     "patch 2    TPDO7     R8z=1000.00 Ω R8x=1414.20 Ω R8y=1414.20 Ω",
                     "heartbeat patch 1    heartbeat boot-up"]:
        assert expected in text


def test_sniff_summary_and_json(capture: Capture) -> None:
    record = capture.record
    by_service: dict[str, int] = {}
    for msg in capture.sent:
        name = str(route(msg).service)
        by_service[name] = by_service.get(name, 0) + 1
    assert record["frames"] == len(capture.sent)
    assert record["by_service"] == by_service
    assert by_service["pdo"] == 2 * 7 * SYNCS and by_service["sync"] == SYNCS
    anomalies = dict(record["anomalies"])  # type: ignore[call-overload]
    # each patch is known once its heartbeat ran and its 7 TPDOs came together: with the
    # seventh of the first cycle; its first six are named unattributed, never guessed
    assert anomalies.pop("unattributed_frames") == 2 * 6
    assert len(anomalies.pop("unattributed_cob_ids")) == 2 * 6
    assert anomalies == {
        "missed_sync": 0, "incomplete_samples": 0, "complete_samples": 2 * (SYNCS - 1),
        "heartbeat_gaps": 0, "unknown_frames": 0, "unknown_cob_ids": [], "error_frames": 0}
    assert record["recording"] == {"path": str(capture.folder / "live.pcap"),
                                   "frames": len(capture.sent),
                                   "files": [str(capture.folder / "live.pcap")]}
    assert record["stopped_by"] == "SIGINT"
    assert f"recorded {len(capture.sent)} frames to" in capture.summary
    assert "anomalies: missed SYNC 0, incomplete samples 0 of 10" in capture.summary


def test_ctrl_c_keeps_the_whole_recording(capture: Capture) -> None:
    with Recording(capture.folder / "live.pcap") as recording:
        got = _by_cob_id(recording)
    # Every frame, in each sender's order: two nodes sending at once on the virtual bus may
    # reach two receivers (the sniffer, the test's listener) in either order.
    assert got == _by_cob_id(capture.sent)  # exact: frames, bytes
    assert sorted(p.name for p in capture.folder.iterdir()) == \
        ["live.pcap", "s.json", "stderr", "stdout"]  # no temp file left


def _by_cob_id(frames: Iterable[can.Message]) -> dict[int, list[bytes]]:
    """Each COB-ID's payloads in the order they came: one node's frames keep their order."""
    out: dict[int, list[bytes]] = {}
    for m in frames:
        out.setdefault(m.arbitration_id, []).append(bytes(m.data))
    return out


WIRESHARK_TYPES = {  # our service -> how tshark's CANopen dissector starts its Info column
    Service.NMT: "NMT:", Service.SYNC: "SYNC", Service.EMCY: "EMCY", Service.PDO: "PDO",
    Service.SDO: "Default-SDO", Service.HEARTBEAT: "NMT Error Control",
}


def tshark_types(path: Path) -> list[tuple[str, str, str]]:
    """(protocol, node-ID, Info) per frame as Wireshark's tshark decodes a SocketCAN pcap."""
    run = children.run(
        ["tshark", "-r", str(path), "-d", "can.subdissector,canopen", "-T", "fields",
         "-e", "_ws.col.Protocol", "-e", "canopen.node_id", "-e", "_ws.col.Info"], timeout=120)
    assert run.returncode == 0, run.stderr
    return [tuple(line.split("\t")) for line in run.stdout.splitlines()]  # type: ignore[misc]


def assert_wireshark_agrees(path: Path, services: set[Service]) -> None:
    with Recording(path) as recording:
        frames = list(recording)
    decoded = tshark_types(path)
    assert len(decoded) == len(frames)
    seen = set()
    for number, (msg, (protocol, node, info)) in enumerate(zip(frames, decoded, strict=True), 1):
        where = route(msg)
        assert protocol == "CANopen", (number, protocol, info)
        assert info.startswith(WIRESHARK_TYPES[where.service]), (number, where, info)
        if where.node is not None:
            assert int(node, 0) == where.node, (number, where, node)
        seen.add(where.service)
    assert seen == services


@pytest.mark.skipif(shutil.which("tshark") is None,
                    reason="tshark is not on PATH (CI installs it with `apt-get install tshark`)")
def test_wireshark_decodes_the_pcap(capture: Capture) -> None:
    assert_wireshark_agrees(capture.folder / "live.pcap", set(WIRESHARK_TYPES))


def test_live_view_renders_a_snapshot() -> None:
    decoder = _told(1, 2)
    sniffer = Sniffer(decoder)
    for msg in _sync_trace():
        sniffer.on_message_received(msg)
    console = Console(record=True, width=200, height=60)
    stats = ViewStats(redraws=3, redraws_skipped=1)
    console.print(render(sniffer.snapshot(), decoder, FrameFilter(), stats, "skin sniff test",
                         2.0, rows=40))
    text = console.export_text()
    assert "skin sniff test" in text and "redraws 3 (skipped 1)" in text
    assert "missed SYNC 1  incomplete samples 5/12  heartbeat gaps 1  unknown 3 (2 ids)  " \
        "unattributed 1 (1 ids)" in text
    assert "SYNC counter 6" in text
    only_sync = Console(record=True, width=200)
    only_sync.print(render(sniffer.snapshot(), decoder, FrameFilter(services=["sync"]),
                           ViewStats(), "x", 2.0, rows=40))
    assert "181" not in only_sync.export_text()


def test_live_view_runs_and_stops_by_itself(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["sniff", "-i", "virtual", "-c", "live-view", "--view", "live", "--seconds", "0.3",
                 "--refresh", "20", "--json", str(tmp_path / "s.json")])
    assert code == 0
    view = json.loads((tmp_path / "s.json").read_text())["view"]
    assert view["mode"] == "live" and view["redraws"] >= 1
    assert "0 frames in" in capsys.readouterr().out


def test_bad_arguments_fail_before_the_bus_opens(tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    def no_bus(*args: object, **kwargs: object) -> None:
        raise AssertionError("the bus was opened")

    monkeypatch.setattr(busopen, "open_bus", no_bus)
    for argv, message in [
        (["--record", str(tmp_path / "x.txt")], "--record: unknown recording format '.txt'"),
        (["--eds", "3=missing.eds"], "eds: no shipped EDS 'missing.eds'"),
        (["--rotate-size", "1M"], "--rotate-size/--rotate-seconds: rotate a recording: give "
                                  "--record FILE too"),
    ]:
        assert main(["sniff", *argv]) == 1
        assert message in capsys.readouterr().err
    for argv, message in [
        (["--seconds", "0"], "argument --seconds: must be > 0 s"),
        (["--record", str(tmp_path / "r.log"), "--rotate-seconds", "0"],
         "argument --rotate-seconds: must be > 0 s"),
        (["--record", str(tmp_path / "r.log"), "--rotate-size", "10T"],
         "argument --rotate-size: must be in 1.0 KiB..1.0 TiB"),
    ]:
        with pytest.raises(SystemExit) as usage:
            main(["sniff", *argv])
        assert usage.value.code == 2 and message in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_rotated_capture_names_its_files(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    frames = [can.Message(arbitration_id=0x181, data=k.to_bytes(8, "little"),
                          is_extended_id=False) for k in range(400)]

    def send() -> None:
        try:
            wait_until(lambda: listening("rotate"), what="skin sniff listening")
            with can.Bus(interface="virtual", channel="rotate") as bus:
                for msg in frames:
                    bus.send(msg)
                wait_until(lambda: read_out("rotate", bus), what="skin sniff read them all")
        finally:
            ctrl_c()  # Ctrl-C: the sniffer ends, keeping what it recorded

    sender = threading.Thread(target=send)
    sender.start()
    out = tmp_path / "r.pcap"
    code = main(["sniff", "-i", "virtual", "-c", "rotate", "--view", "none", "--seconds", "600",
                 "--record", str(out), "--rotate-size", "4k", "--json", str(tmp_path / "s.json")])
    sender.join()
    assert code == 0
    files = json.loads((tmp_path / "s.json").read_text())["recording"]["files"]
    assert [Path(f).name for f in files] == ["r.pcap", "r.001.pcap", "r.002.pcap", "r.003.pcap"]
    counts = []
    for file in files:
        with Recording(file) as recording:
            counts.append(sum(1 for _ in recording))
    assert counts == [128, 128, 128, 16]  # 24 + 32 x 128 bytes reach 4 KiB
    assert f"recorded 400 frames to {out} .. {files[-1]} (4 files)" in capsys.readouterr().out


def test_line_printer_filters_batches_and_counts_drops(monkeypatch: pytest.MonkeyPatch) -> None:
    import io

    from skin.commands.sniff import view as sniff_view

    decoder = ServiceDecoder()
    out = io.StringIO()
    stats = ViewStats()
    monkeypatch.setattr(sniff_view, "_LINE_QUEUE", 3)
    printer = sniff_view.LinePrinter(decoder, FrameFilter(nodes=[1]), out, stats)  # not started
    frames = [_msg(1.5, 0x181, bytes.fromhex("204e7c6e7c6e204e")), _msg(1.6, 0x182, bytes(8)),
              _msg(1.7, 0x701, b"\x05"), _msg(1.8, 0x181, bytes.fromhex("ffff000000000000")),
              _msg(1.9, 0x601, bytes.fromhex("4018100200000000")), _msg(2.0, 0x181, bytes(8))]
    for msg in frames:
        where = route(msg)
        printer.on_frame(msg, where, decoder.decode(msg, where)
                         if where.service is Service.SDO else None)
    assert stats.lines_dropped == 2  # node 1 frames 4 and 5 found the queue (3) full
    lines = printer.format(list(printer._pending))
    assert lines == [
        "1.500000 181 [8] 20 4e 7c 6e 7c 6e 20 4e pdo       patch 1    TPDO1     "
        "R0z=1000.00 Ω R0x=1414.20 Ω R0y=1414.20 Ω R1z=1000.00 Ω\n",
        "1.700000 701 [1] 05                      heartbeat patch 1    heartbeat operational\n",
        "1.800000 181 [8] ff ff 00 00 00 00 00 00 pdo       patch 1    TPDO1     "
        "R0z=open R0x=short R0y=short R1z=short\n",
    ]
