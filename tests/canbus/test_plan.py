"""``skin plan`` and canbus.busload: every frame that crosses a bus, counted."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canbus import busload, frametime
from canbus.busload import plan
from canbus.sizing import size
from tests.support.rigs import children


def _skin_plan(*args: str) -> subprocess.CompletedProcess[str]:
    return children.run([sys.executable, "-m", "skin.cli", "plan", *args], timeout=120)


def test_frame_bounds_match_the_hand_calculation() -> None:
    # classic, 8 bytes: 34 + 64 = 98 bits under stuffing + 13 = 111; worst + (98 - 1) // 4
    assert frametime.classic_frame_bits(8, worst_case_stuffing=False) == 111
    assert frametime.classic_frame_bits(8, worst_case_stuffing=True) == 135
    assert int(1e6 / 135) == 7407 and int(1e6 / 111) == 9009
    # SYNC with its counter: 42 stuffed bits + 13 = 55, worst + 10
    assert frametime.classic_frame_bits(1, worst_case_stuffing=True) == 65
    # 29-bit id: 20 more stuffed bits (SRR, IDE, 18 id bits): 131 and 131 + 29
    assert frametime.classic_frame_bits(8, worst_case_stuffing=True, extended=True) == 160
    # CAN FD, 64 bytes: 29 nominal (SOF..BRS 17, ACK, delimiter, EOF, IFS) + 550 data bits
    # (ESI, DLC, 512, stuff count 4, CRC-21, 7 fixed stuff bits, CRC delimiter) = 579, as
    # Linux's can_frame_bits(); worst: 3 stuff bits before BRS and (534 - 2) // 4 = 133 in
    # all: 712, Linux's figure too.
    assert frametime.fd_frame_bits(64, worst_case_stuffing=False) == (29, 550)
    assert frametime.fd_frame_bits(64, worst_case_stuffing=True) == (32, 680)
    assert frametime.fd_frame_bits(64, worst_case_stuffing=False, brs=False) == (579, 0)
    # 29-bit id: 598 bits; Linux's worst case is 736, one more: it allows a dynamic stuff bit
    # after the last data bit, which ISO replaces by the fixed stuff bit.
    assert sum(frametime.fd_frame_bits(64, worst_case_stuffing=False, extended=True)) == 598
    assert sum(frametime.fd_frame_bits(64, worst_case_stuffing=True, extended=True)) == 735
    assert frametime.fd_length(55) == frametime.fd_length(57) == 64
    assert frametime.fd_length(19) == 20


def test_payloads_are_the_project_s_mappings() -> None:
    assert frametime.patch_payloads("xyz", fd=False) == [8] * 6 + [6]
    assert frametime.patch_payloads("z", fd=False) == [6] * 3
    assert frametime.force_payloads(fd=False) == [8] * 8  # 7 of forces, the contact's TPDO 8
    assert frametime.force_payloads(fd=False, contact=False) == [8] * 7
    # FD: the codes and the SYNC counter in one frame; forces: 27 + 0x2005 + counter, and
    # the contact's net Fz, CoP and state
    assert frametime.patch_payloads("xyz", fd=True) == [55]
    assert frametime.patch_payloads("z", fd=True) == [19]
    assert frametime.force_payloads(fd=True) == [64]
    assert frametime.force_payloads(fd=True, contact=False) == [57]


def test_one_patch_cycle_by_hand() -> None:
    p = plan(1, 1000 / 7, "xyz", 1_000_000, forces="none", heartbeat_ms=0,
             force_heartbeat_ms=0)
    assert p.frames_per_sample == 7 and p.force_frames_per_sample == 0
    assert p.frames_per_s == pytest.approx(1000 + 1000 / 7)  # the TPDOs and the SYNC
    bits6, bits6w = 47 + 48, 47 + 48 + (34 + 48 - 1) // 4
    cycle_best, cycle_worst = 55 + 6 * 111 + bits6, 65 + 6 * 135 + bits6w
    assert p.cycle_ms_best == pytest.approx(cycle_best / 1000)
    assert p.load_best_pct == pytest.approx(100 * cycle_best / 7 / 1000)
    assert p.load_worst_pct == pytest.approx(100 * cycle_worst / 7 / 1000)
    assert plan(1, p.max_rate_hz, "xyz", 1_000_000, forces="none", heartbeat_ms=0,
                force_heartbeat_ms=0).load_worst_pct == pytest.approx(70.0)


def test_forces_and_heartbeats_are_counted() -> None:
    p = plan(16, 100, "xyz", 1_000_000)
    # 16 x 100 x (7 patch + 8 force) + 100 SYNC + 16 x 10 patch and 16 x 1 force heartbeats
    assert p.frames_per_s == pytest.approx(24_000 + 100 + 160 + 16)
    (bus,) = p.buses
    assert bus.frames_per_s == pytest.approx({"sync": 100, "patch_pdo": 11_200,
                                              "heartbeat": 176, "force_pdo": 12_800})
    without = plan(16, 100, "xyz", 1_000_000, contact=False)  # [contact] enabled = false
    assert without.buses[0].frames_per_s["force_pdo"] == pytest.approx(11_200)
    assert without.force_frames_per_sample == 7 and p.force_frames_per_sample == 8
    assert bus.force_nodes == tuple(range(65, 81))
    # with max_rate_hz the worst case sits at the target, heartbeats included
    at_max = plan(16, p.max_rate_hz, "xyz", 1_000_000)
    assert at_max.load_worst_pct == pytest.approx(70.0)


def test_four_patches_need_about_6_ms_of_wire_per_cycle() -> None:
    # issue 11: 4 patches, 3-axis, forces on the same bus: about 6.3 ms per 10 ms cycle
    p = plan(4, 100, "xyz", 1_000_000, contact=False)
    assert p.cycle_ms_best < 6.3 < p.cycle_ms_worst
    assert p.fits and p.over_target  # 62 to 76 % of the wire
    # the contact PDO: 4 more 8-byte frames (111 to 135 bits each) a cycle
    with_contact = plan(4, 100, "xyz", 1_000_000)
    assert with_contact.cycle_ms_best == pytest.approx(p.cycle_ms_best + 4 * 0.111)
    assert with_contact.cycle_ms_worst == pytest.approx(p.cycle_ms_worst + 4 * 0.135)


def test_buses_share_the_patches_and_each_has_its_sync() -> None:
    p = plan(8, 100, "xyz", 1_000_000, buses=3)
    assert [b.patches for b in p.buses] == [(1, 2, 3), (4, 5, 6), (7, 8)]
    assert all(b.frames_per_s["sync"] == 100 for b in p.buses)
    assert p.worst_bus == "bus 0" and p.load_worst_pct == p.buses[0].load_worst_pct
    other = plan(8, 100, "xyz", 1_000_000, buses=2, forces="other-bus")
    *patch_buses, forces = other.buses
    assert forces.name == "forces" and forces.force_nodes == tuple(range(65, 73))
    assert set(forces.frames_per_s) == {"force_pdo", "heartbeat"}  # event-driven: no SYNC
    assert all("force_pdo" not in b.frames_per_s for b in patch_buses)
    assert busload.spread([1, 2, 3], 3) == [(1,), (2,), (3,)]
    with pytest.raises(ValueError, match="would carry none"):
        plan(2, 100, "xyz", 1_000_000, buses=3)


def test_the_bar_classic_does_not_fit_can_fd_does(tmp_path: Path) -> None:
    classic, fd = tmp_path / "classic.json", tmp_path / "fd.json"
    run = _skin_plan("--patches", "8", "--rate", "100", "--mode", "xyz", "--bitrate",
                     "1000000", "--json", str(classic))
    assert run.returncode == 0 and "does not fit" in run.stderr
    assert run.stderr.count("\n") == 1
    c = json.loads(classic.read_text())
    assert c["force_frames_per_sample"] == 8 and c["buses"][0]["frames_per_s"]["force_pdo"] == 6400
    assert c["load_best_pct"] > 100 and not c["fits"]
    run = _skin_plan("--patches", "8", "--rate", "100", "--mode", "xyz", "--bitrate",
                     "1000000", "--fd", "--data-bitrate", "5000000", "--json", str(fd))
    assert run.returncode == 0 and run.stderr == ""
    f = json.loads(fd.read_text())
    assert f["fits"] and f["load_worst_pct"] < 70
    assert f["max_patch_samples_per_s"] >= 5 * c["max_patch_samples_per_s"]
    # the keys of the first planner still mean what they meant
    for key in ("patches", "rate_hz", "mode", "bitrate", "data_bitrate", "frames_per_sample",
                "frames_per_s", "load_best_pct", "load_worst_pct", "target_pct", "max_rate_hz",
                "over_target"):
        assert key in c
    assert c["frames_per_sample"] == 7 and f["frames_per_sample"] == 1
    assert f["data_bitrate"] == 5_000_000


def test_a_plan_under_100_but_over_target_warns_so() -> None:
    run = _skin_plan("--patches", "4", "--rate", "100", "--forces", "none", "--target", "30")
    assert run.returncode == 0
    assert "warning: worst-case load" in run.stderr and "30 % target" in run.stderr
    assert "bus 0 (patches 1-4)" in run.stdout


def test_a_skin_whose_heartbeats_alone_fill_the_bus_is_told_no_rate_fits() -> None:
    """2,000 patches on one bus: their heartbeats alone are over the target, so the advice
    is the buses it needs, not a rate of 0.0 Hz."""
    run = _skin_plan("--patches", "2000", "--rate", "100", "--mode", "xyz", "--fd")
    assert run.returncode == 0
    assert "no sample rate fits bus 0 (its heartbeats alone are over the 70 % target)" \
        in run.stderr and "0.0 Hz" not in run.stderr
    assert "or use 667 buses of CAN 1,000,000 bit/s or 100 buses of CAN FD" in run.stderr


@pytest.mark.parametrize(("args", "message", "status"), [
    (["--buses", "0"], "argument --buses: must be in 1..100000, got '0'", 2),
    (["--buses", "9"], "a bus would carry none", 1),
    (["--fd", "--data-bitrate", "500000"], "below the nominal bitrate", 1),
    (["--heartbeat-ms", "-1"], "argument --heartbeat-ms: must be in 0..65535 ms", 2),
    (["--rate", "inf"], "argument --rate: must be a finite number", 2),
])
def test_bad_plans_fail_in_one_line(args: list[str], message: str, status: int,
                                    tmp_path: Path) -> None:
    out = tmp_path / "plan.json"
    run = _skin_plan("--patches", "8", "--rate", "100", "--json", str(out), *args)
    assert run.returncode == status and message in run.stderr
    assert run.stderr.count("\n") == 1 and not out.exists()


@settings(max_examples=60, deadline=None)
@given(patches=st.integers(1, 24), rate=st.floats(10, 1000), mode=st.sampled_from(["z", "xyz"]),
       fd=st.booleans(), forces=st.sampled_from(["same-bus", "other-bus", "none"]),
       target=st.floats(20, 95))
def test_the_buses_needed_are_the_fewest_that_keep_every_bus_under_the_target(
        patches: int, rate: float, mode: str, fd: bool, forces: busload.Forces,
        target: float) -> None:
    data = 5_000_000 if fd else None
    sized = size(patches, rate, mode, 1_000_000, data_bitrate=data, target_pct=target,
                 forces=forces)

    def patch_plan(buses: int) -> busload.Plan:
        return plan(patches, rate, mode, 1_000_000, data_bitrate=data, target_pct=target,
                    buses=buses, forces="none" if forces == "other-bus" else forces)

    if sized.buses is None:
        assert patch_plan(patches).over_target  # one patch a bus is already too much
    else:
        at = patch_plan(sized.buses)
        assert all(b.load_worst_pct <= target for b in at.buses)
        assert sized.buses == 1 or patch_plan(sized.buses - 1).over_target
        assert sized.max_rate_hz <= at.max_rate_hz + 1e-9
        assert max(b.load_worst_pct for b in at.buses) <= sized.load_worst_pct + 1e-9
    if forces != "other-bus":
        assert sized.force_buses == 0


def test_plan_answers_the_sizing_question(tmp_path: Path) -> None:
    """16 patches at 200 Hz (3-axis, forces with the contact PDO on each patch's bus): 644 %
    of one classic bus."""
    out = tmp_path / "plan.json"
    run = _skin_plan("--patches", "16", "--rate", "200", "--json", str(out))
    assert run.returncode == 0
    assert "buses needed for 16 patches x 200 Hz under the 70 % target" in run.stdout
    rows = {line.split("  ")[0]: line.split() for line in run.stdout.splitlines()
            if line.startswith("CAN ")}
    assert rows["CAN 1,000,000 bit/s"][-6:-3] == ["16", "1", "41.5"]
    assert rows["CAN FD 1,000,000/5,000,000 bit/s"][-6:-3] == ["2", "8", "55.6"]
    assert "or use 16 buses of CAN 1,000,000 bit/s or 2 buses of CAN FD" in run.stderr
    sizing = json.loads(out.read_text())["sizing"]
    assert (sizing["classic"]["buses"], sizing["fd"]["buses"]) == (16, 2)
    assert sizing["fd"]["max_rate_hz"] == pytest.approx(252.19, abs=0.01)
