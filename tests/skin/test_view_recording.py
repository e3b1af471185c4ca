"""`skin view` on a recording of the indenter scene: what it reads, draws and prints.

One live run (module fixture): two simulated patches of the indenter scene (as `skin demo`
serves them) and the host manager on a virtual bus, recorded to .log by a Recorder.
"""

from __future__ import annotations

import itertools
import json
import threading
from collections import Counter
from pathlib import Path

import can
import can.interfaces.virtual
import numpy as np
import pytest
from matplotlib import colormaps
from PIL import Image

from canbus.master.forceframes import forces_to_mN
from canbus.tools.recording import Recording
from sim import Simulator
from skin.cli import main
from skin.commands.demo import demo_scene
from skin.commands.view.layout import Layout
from skin.commands.view.plot import moment_picture
from skin.commands.view.recorded import moment_view
from skin.commands.view.report import title
from skin.commands.view.sources import (
    force_specs,
    recorded_resistances,
    recorded_samples,
    recording_times,
)
from tests.support.rigs.view import HostRun, record_host_run, until

CYCLES = 80


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> HostRun:
    scene = demo_scene("indenter", 2)
    simulated = Simulator(scene).run(CYCLES + 40)
    path = tmp_path_factory.mktemp("view") / "indenter.log"
    return record_host_run(path, simulated.resistance_ohm, scene.node_ids, cycles=CYCLES,
                           channel="view-indenter")


def _published(run: HostRun, patch: int) -> list:
    return [f for f in run.frames if f.patch == patch and f.published]


def _void(sample: object) -> bool:
    """All-invalid and incomplete: a cycle with nothing usable, or the host's withdrawal
    of a patch it found lost (sent on the bus, not a frame of its API)."""
    return not sample.complete and not sample.valid.any()  # type: ignore[attr-defined]


def test_the_reader_gets_every_published_sample_of_the_run_bit_for_bit(run: HostRun) -> None:
    samples = recorded_samples(run.path, specs=force_specs(run.config))
    by_bus = recorded_samples(run.path)  # no config: what the bus shows names each node
    for patch in (1, 2):
        told = [s for s in samples if s.patch == patch]
        seen = [s for s in by_bus if s.patch == patch]
        # named by its heartbeat and its first whole set of default PDOs, that sample
        # included: every sample, the same as a reader told the config reads
        assert [s.timestamp for s in seen] == [s.timestamp for s in told]
        for a, b in zip(seen, told, strict=True):
            np.testing.assert_array_equal(a.force_N, b.force_N)
            np.testing.assert_array_equal(a.valid, b.valid)
        want = _published(run, patch)
        got = told
        assert len(got) >= len(want) >= CYCLES
        assert sum(map(_void, got)) - sum(map(_void, want)) == len(got) - len(want)
        want = [f for f in want if not _void(f)]
        got = [s for s in got if not _void(s)]
        assert len(got) == len(want)
        for frame, sample in zip(want, got, strict=True):
            mN, on_bus = forces_to_mN(frame.force_N, frame.valid)
            np.testing.assert_array_equal(sample.valid, on_bus)
            np.testing.assert_array_equal(sample.force_N,
                                          np.where(on_bus[:, None], mN / 1000.0, 0.0))
            assert sample.complete == frame.complete and sample.force_node == patch + 64


def test_decoding_the_recording_here_gives_the_host_s_own_frames(run: HostRun) -> None:
    """Every sample the live host completed is decoded offline bit for bit. The live host
    closes a cycle when it sends the next SYNC, so on a busy machine, whose receive thread
    had not yet taken the cycle's last frames then, it has fewer valid taxels than the
    recording holds: then the offline decode has every taxel the host had, alike."""
    decoded = recorded_samples(run.path, decode=run.config)
    complete = 0
    for patch in (1, 2):
        want = [f for f in run.frames if f.patch == patch]
        got = [f for f in decoded if f.patch == patch]
        assert [f.cycle for f in got] == [f.cycle for f in want]
        for a, b in zip(got, want, strict=True):
            if b.complete:
                complete += 1
                np.testing.assert_array_equal(a.force_N, b.force_N)
                np.testing.assert_array_equal(a.valid, b.valid)
                assert a.complete
            else:
                assert not (b.valid & ~a.valid).any(), "a taxel only the live host had"
                np.testing.assert_array_equal(a.force_N[b.valid], b.force_N[b.valid])
    assert complete >= len(run.frames) // 2, "the host completed too few samples to compare"


def _latest(samples: list, t: float) -> dict[int, object]:
    """Each patch's last sample at or before bus time ``t``."""
    out: dict[int, object] = {}
    for sample in samples:
        if sample.timestamp <= t:
            out[sample.patch] = sample
    return out


def _on_bus(sample: object) -> tuple[list[int], list[bool]]:
    mN, valid = forces_to_mN(sample.force_N, sample.valid)  # type: ignore[attr-defined]
    return mN.ravel().tolist(), valid.tolist()


def _pressed_moment(run: HostRun) -> tuple[float, int, int, float]:
    """A time (s from the start) at which patch 1 is pressed: (t, pressed taxel, idle
    taxel, its Fz). Just before a SYNC, where every patch's last sample read from the force
    PDOs is the one decoding the patches gives: a cycle the host published late or
    incomplete (a loaded machine) is no such moment."""
    times = recording_times(run.path)
    with Recording(run.path) as recording:
        syncs = np.array([m.timestamp for m in recording if m.arbitration_id == 0x80])
    on_bus = recorded_samples(run.path)
    decoded = recorded_samples(run.path, decode=run.config)
    for sync in syncs[1:]:
        t = sync - 0.0005
        bus, dec = _latest(on_bus, t), _latest(decoded, t)
        if set(bus) != {1, 2} or set(dec) != set(bus) or \
                any(_on_bus(bus[p]) != _on_bus(dec[p]) for p in bus):
            continue
        fz = bus[1].force_N[:, 2]  # type: ignore[attr-defined]
        if fz.max() >= 1.5 and np.abs(fz).min() < 0.1:
            return (t - times.first, int(fz.argmax()), int(np.abs(fz).argmin()),
                    float(fz.max()))
    raise AssertionError("the indenter never pressed patch 1 to 1.5 N")


def _colour(image: np.ndarray, picture: object, patch: int, taxel: int,
            pitch_mm: float) -> np.ndarray:
    """The most common colour over the inner part of a taxel (text and arrows are small)."""
    cx, cy = picture.centres[patch][taxel]  # type: ignore[attr-defined]
    seen: Counter[tuple[int, ...]] = Counter()
    for dx in np.linspace(-0.35, 0.35, 8):
        for dy in np.linspace(-0.35, 0.35, 8):
            col, row = picture.pixel_at(cx + dx * pitch_mm, cy + dy * pitch_mm)  # type: ignore[attr-defined]
            seen[tuple(int(c) for c in image[row, col, :3])] += 1
    return np.array(seen.most_common(1)[0][0], dtype=float)


def test_the_png_shows_the_pressed_taxel_in_a_clearly_other_colour(
        run: HostRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    at, pressed, idle, fz = _pressed_moment(run)
    out = tmp_path / "out.png"
    assert main(["view", str(run.path), "--png", str(out), "--at", f"{at:.6f}"]) == 0
    assert capsys.readouterr().out.startswith(f"wrote {out} (t = ")
    image = np.asarray(Image.open(out).convert("RGB"))
    times = recording_times(run.path)
    t = times.first + float(f"{at:.6f}")
    view = moment_view(str(run.path), t, Layout(), 5.0)
    picture = moment_picture(view.state(t), scale_N=5.0, time_s=t - times.first,
                             title=title(str(run.path), False))
    assert image.shape[:2] == (picture.figure.bbox.height, picture.figure.bbox.width)
    pitch = 1000.0 * view.layout.pitch_m
    hot, cold = (_colour(image, picture, 1, k, pitch) for k in (pressed, idle))
    assert np.linalg.norm(hot - cold) > 150.0, (hot, cold)  # of 441 between black and white
    expected = 255.0 * np.array(colormaps["inferno"](fz / 5.0)[:3])
    assert np.abs(hot - expected).max() < 12.0, (hot, expected)  # Fz on the stated scale
    assert np.abs(cold - 255.0 * np.array(colormaps["inferno"](0.0)[:3])).max() < 12.0


def test_the_snapshot_reads_the_same_from_the_force_pdos_and_decoding_the_patches(
        run: HostRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    at, pressed, _, fz = _pressed_moment(run)
    config = tmp_path / "host.toml"
    config.write_text("[host]\nsync_period_ms = 10.0\n[[patches]]\nnode_id = 1\n"
                      "position_m = [0.0, 0.0]\n[[patches]]\nnode_id = 2\n"
                      "position_m = [0.05, 0.0]\n", encoding="utf-8")
    texts = []
    for extra in ([], ["--decode", "--config", str(config)]):
        assert main(["view", str(run.path), "--snapshot", "--at", f"{at:.6f}", *extra]) == 0
        texts.append(capsys.readouterr().out)
    bus, decoded = (t.splitlines() for t in texts)
    assert bus[0].startswith(f"skin view {run.path.name}  t {at:.3f} s  2 patches")
    assert decoded[0].startswith(f"skin view {run.path.name} (decoded)  t {at:.3f} s")
    # the same forces both ways; the rates differ a little (sample times: the last force
    # PDO's on the bus, the SYNC's when decoded)
    assert [line for line in bus[1:] if " Hz " not in line] == \
        [line for line in decoded[1:] if " Hz " not in line]
    row = ["│ " in line for line in bus].index(True) + 2 - pressed // 3  # +y up
    cell = bus[row][2 + 6 * (pressed % 3):8 + 6 * (pressed % 3)]
    assert f"{round(fz, 1):5.1f}" in cell.replace("◆", " ")  # ◆: the CoP's nearest taxel
    assert sum(line.count("◆") for line in bus) >= 1 and any(
        line.startswith("CoP") for line in bus)  # the contact lines are there


def test_a_gif_animates_the_span(run: HostRun, tmp_path: Path,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    out, record = tmp_path / "span.gif", tmp_path / "gif.json"
    assert main(["view", str(run.path), "--gif", str(out), "--from", "0.3", "--to", "0.6",
                 "--fps", "20", "--json", str(record)]) == 0
    with Image.open(out) as gif:
        assert gif.n_frames == 7
        frames = []
        for k in range(gif.n_frames):
            gif.seek(k)
            frames.append(np.asarray(gif.convert("RGB")))
    assert any(np.any(a != b) for a, b in itertools.pairwise(frames))
    assert json.loads(record.read_text())["animation_frames"] == 7
    assert "wrote " in capsys.readouterr().out


def test_a_taxel_trace_with_its_raw_resistances(run: HostRun, tmp_path: Path) -> None:
    _, pressed, _, _ = _pressed_moment(run)
    out, record = tmp_path / "trace.png", tmp_path / "trace.json"
    assert main(["view", str(run.path), "--plot", str(out), "--patch", "1", "--taxel",
                 str(pressed), "--raw", "--json", str(record)]) == 0
    figures = json.loads(record.read_text())
    frames = _published(run, 1)
    assert figures["samples"] == len(frames)
    assert figures["invalid"] == sum(not f.valid[pressed] for f in frames)
    assert figures["peak_Fz_N"] == pytest.approx(
        max(f.force_N[pressed, 2] for f in frames if f.valid[pressed]), abs=5e-4)
    raw = recorded_resistances(run.path, 1)
    assert figures["raw_samples"] == len(raw) >= len(frames)
    assert Image.open(out).size == (900, 700)  # two panels: forces over resistances


def test_a_recording_played_fast_without_a_terminal_prints_the_last_frame_and_a_summary(
        run: HostRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    record = tmp_path / "play.json"
    assert main(["view", str(run.path), "--fast", "--json", str(record)]) == 0
    out = capsys.readouterr().out
    assert "patch 1" in out and "2 patches: " in out
    figures = json.loads(record.read_text())
    assert figures["samples"] >= sum(f.published for f in run.frames)
    assert figures["figures"]["sent"] == recording_times(run.path).frames


def test_the_view_reads_a_live_bus(run: HostRun, tmp_path: Path,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    from canbus.tools.replay import Replayer

    record = tmp_path / "bus.json"
    code: list[int] = []
    runner = threading.Thread(target=lambda: code.append(main(
        ["view", "-i", "virtual", "-c", "view-live-bus", "--seconds", "2.5", "--json",
         str(record)])))
    runner.start()
    try:
        until(lambda: "view-live-bus" in can.interfaces.virtual.channels, "the view's bus")
        with can.Bus(interface="virtual", channel="view-live-bus") as bus:
            Replayer(bus, run.path, realtime=False).run()
    finally:
        runner.join(15.0)
    assert not runner.is_alive() and code == [0]
    figures = json.loads(record.read_text())
    assert figures["source"] == "virtual:view-live-bus (from -i)"
    assert figures["samples"] == len(recorded_samples(run.path))
