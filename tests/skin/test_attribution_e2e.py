"""`skin sniff --view lines` and `skin view --snapshot` on a recording of the bus of
`examples/host.toml`, with and without `--config`: no force value is shown under a node
that did not send it.

The example gives patch 3's force node 100 the COB-IDs 0x1E0..0x1E6: the default TPDO 1 of
nodes 96..102, and 0x1E4, node 100's own default TPDO 1, carries its TPDO 5. One live run
(module fixture): the example's host (SDO set-up, NMT, SYNC, three force nodes) and its
three patches (patch 2 in z-only mode, patch 3 pressed) on a virtual bus, recorded to .log
from before the host starts, the host's published force frames kept as the truth.
"""

from __future__ import annotations

import re
import threading
from dataclasses import dataclass, replace
from pathlib import Path

import can
import numpy as np
import pytest

from canbus import codes
from canbus.device.source import ArraySource
from canbus.master.dataplane import ForceFrame
from canbus.master.forceframes import forces_to_mN
from canbus.master.hostconfig import HostConfig, load_host_config
from canbus.tools.attribution import Attribution
from canbus.tools.pdo_dictionary import Dictionary
from canbus.tools.recorder import Recorder
from canbus.tools.recording import Recording
from canbus.tools.replay import Replayer
from canbus.tools.services import ServiceDecoder
from skin.cli import main
from skin.commands.common.known_nodes import known_nodes
from skin.commands.view.layout import Layout
from skin.commands.view.recorded import moment_view
from skin.constants import DEFAULT_CONSTANTS
from skin.tripod import resistance_from_force
from tests.support.rigs.recorded_host import recorded_host
from tests.support.rigs.waiting import wait_until

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "host.toml"
CUSTOM = set(range(0x1E0, 0x1E7))
CYCLES = 40
LINE = re.compile(r"(\S+) (\S+) \[(\d+)\] (.{23}) (.{9}) (.{10}) (\S+) +(.*)")


@dataclass
class Run:
    path: Path
    config: HostConfig
    frames: list[ForceFrame]
    stats: dict[str, int]
    lost: list[int]


def _samples() -> np.ndarray:
    force = np.zeros((CYCLES + 40, 3, 9, 3))
    for k in range(force.shape[0]):
        force[k, 0, k % 9] = (0.1, -0.1, 0.3)
        force[k, 1, (2 * k) % 9] = (0.0, 0.0, 0.8)
        force[k, 2, 4] = (0.4, 0.2, 1.0 + 0.05 * (k % 20))  # patch 3: a press that grows
    r = resistance_from_force(force, DEFAULT_CONSTANTS)
    lsb = DEFAULT_CONSTANTS.resistance_lsb_ohm
    return codes.resistance_to_code(r, lsb).astype(np.float64) * lsb


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Run:
    folder = tmp_path_factory.mktemp("example")
    channel = "example-bus"
    # heartbeats 1 s apart: a patch is lost after 1.5 s without one, which a loaded machine
    # does not stall for; at the example's 100 ms one late heartbeat loses a patch for a
    # moment, and its PDOs of that moment are, rightly, no channel's (unknown_frames)
    config = replace(load_host_config(EXAMPLE), scan_ms=100, heartbeat_ms=1000)
    lost: list[int] = []

    def on_event(event: object) -> None:
        if getattr(event, "state", None) == "lost":
            lost.append(event.patch)  # type: ignore[attr-defined]

    with recorded_host(channel, config, ArraySource(_samples(), (1, 2, 3)),
                       [Recorder(folder / "example.log")], on_event=on_event) as run:
        wait_until(lambda: sum(f.patch == 3 and f.complete for f in run.frames) >= CYCLES,
                   what=f"{CYCLES} complete samples of patch 3")
    return Run(folder / "example.log", config, run.frames, run.stats, lost)


def _sniff_lines(run: Run, *extra: str) -> list[str]:
    """`skin sniff --view lines` while the recording is replayed onto its bus."""
    channel = f"example-replay{len(extra)}"
    out = run.path.parent / f"lines{len(extra)}.txt"

    def replay() -> None:
        wait_until(lambda: channel in can.interfaces.virtual.channels,
                   what="skin sniff on the bus")
        with can.Bus(interface="virtual", channel=channel) as sender:
            Replayer(sender, run.path, realtime=False).run()

    player = threading.Thread(target=replay)
    player.start()
    import contextlib

    with out.open("w") as handle, contextlib.redirect_stdout(handle):
        code = main(["sniff", "-i", "virtual", "-c", channel, "--view", "lines", "--seconds",
                     "4", *extra])
    player.join()
    assert code == 0
    return out.read_text().splitlines()


def _truth_decoder(config: HostConfig) -> ServiceDecoder:
    return ServiceDecoder(attribution=Attribution(Dictionary(), known_nodes(config)))


@pytest.mark.parametrize("told", [False, True], ids=["without --config", "with --config"])
def test_sniff_lines_show_every_pdo_under_its_sender_or_under_nobody(run: Run,
                                                                      told: bool) -> None:
    lines = _sniff_lines(run, *(["--config", str(EXAMPLE)] if told else []))
    with Recording(run.path) as recording:
        messages = list(recording)
    assert len(lines) == len(messages)  # every frame, in order
    truth = _truth_decoder(run.config)
    under: dict[int, set[str]] = {}
    for line, msg in zip(lines, messages, strict=True):
        true = truth.decode(msg)
        match = LINE.fullmatch(line)
        assert match is not None, line
        cob, service, node, rest = (int(match[2], 16), match[5].strip(), match[6].strip(),
                                    f"{match[7]} {match[8]}")
        label, text = rest.split(" ", 1)
        if label.startswith("TPDO") and text.startswith("contact "):  # "TPDO8 contact"
            label, text = f"{label} contact", text.removeprefix("contact ")
        assert cob == msg.arbitration_id
        if service != "pdo":
            continue
        if not node:  # named by nobody: its bytes, nothing decoded
            assert not told and label == "unattributed" and text == msg.data.hex(" "), line
            continue
        assert node == truth.node_label(true.node) and label == true.label, line
        assert text == true.text, line  # the sender's values, as the sender mapped them
        under.setdefault(cob, set()).add(node)
    on_custom = {cob: nodes for cob, nodes in under.items() if cob in CUSTOM}
    if told:
        assert on_custom == {cob: {"forces 100"} for cob in CUSTOM}
    else:
        assert on_custom == {}  # never nodes 96..102's, nor node 100's TPDO 1
    assert {"forces 65", "forces 66"} <= set().union(*under.values())


def _patches(text: str) -> set[int]:
    return {int(n) for n in re.findall(r"patch (\d+) ", text)}


@pytest.mark.parametrize("told", [False, True], ids=["without --config", "with --config"])
def test_view_snapshot_shows_only_what_each_force_node_sent(
        run: Run, told: bool, capsys: pytest.CaptureFixture[str]) -> None:
    config = ["--config", str(EXAMPLE)] if told else []
    assert main(["view", str(run.path), "--snapshot", *config]) == 0
    captured = capsys.readouterr()
    shown = _patches(captured.out.split("\n\n", 1)[1])
    assert shown == ({1, 2, 3} if told else {1, 2})  # never 32..38, nor patch 36
    if not told:
        assert "0x1E0-0x1E6" in captured.err  # named, left out
    with Recording(run.path) as recording:
        end = max(m.timestamp for m in recording)
    view = moment_view(str(run.path), end, Layout(), 5.0,
                       config=run.config if told else None)
    for patch, status in view.state(end).statuses.items():
        published = [f for f in run.frames if f.patch == patch and f.published]
        sample = status.last
        assert sample is not None and sample.force_node == run.config.patch(patch).force_node
        truth = published[-1]  # the last sample the host published for the patch
        mN, on_bus = forces_to_mN(truth.force_N, truth.valid)
        np.testing.assert_array_equal(sample.valid, on_bus)
        np.testing.assert_array_equal(sample.force_N,
                                      np.where(on_bus[:, None], mN / 1000.0, 0.0))


def test_a_clean_run_counts_no_unknown_frame(run: Run) -> None:
    """The patches' heartbeats, the start-up's SDO scan and set-up, SYNC and NMT are the
    bus's own traffic (bus_frames), not unknown."""
    assert run.lost == [], "a patch was lost during the run: not a clean run"
    assert run.stats["unknown_frames"] == 0
    assert run.stats["bus_frames"] > 2 * CYCLES  # SYNCs at least
