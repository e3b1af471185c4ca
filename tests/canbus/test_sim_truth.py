"""``skin sim run SCENE --truth F.csv``: the true force of every answer, keyed by the SYNC
counter it answers and the SYNC's time; no truth for a patch that did not answer."""

from __future__ import annotations

import json
import time
from pathlib import Path

import can
import canopen
import numpy as np
import pytest

from sim import Simulator, load_scene
from skin.reference import read_reference
from tests.canbus.virtual_channels import run_until_done
from tests.support.rigs.waiting import wait_until


def test_the_truth_of_every_answer(request: pytest.FixtureRequest, tmp_path: Path) -> None:
    channel = f"sim-truth-{request.node.name}"
    master = canopen.Network()
    master.NOTIFIER_CYCLE = 0.05
    master.connect(interface="virtual", channel=channel)
    raw = can.Bus(interface="virtual", channel=channel)
    answers: list[can.Message] = []
    notifier = can.Notifier(raw, [answers.append], timeout=0.05)
    truth, out = tmp_path / "truth.csv", tmp_path / "run.json"
    argv = ["sim", "run", "calibration", "--seed", "7", "-i", "virtual", "-c", channel,
            "--truth", str(truth), "--json", str(out)]
    sent: list[int] = []

    def traffic() -> None:
        wait_until(lambda: any(m.arbitration_id == 0x701 for m in answers), what="boot-up")
        for counter in (1, 2):  # pre-operational: no answer, no truth
            master.send_message(0x080, bytes([counter]))
            time.sleep(0.01)  # pacing: SYNCs 10 ms apart
        master.send_message(0x000, bytes([0x01, 1]))  # NMT start node 1
        wait_until(lambda: any(m.arbitration_id == 0x701 and m.data[0] == 0x05
                               for m in answers), what="node 1's heartbeat: operational")
        for counter in range(3, 43):
            master.send_message(0x080, bytes([counter]))
            sent.append(counter)
            time.sleep(0.01)  # pacing: SYNCs 10 ms apart
        wait_until(lambda: sum(0x180 <= m.arbitration_id < 0x580 for m in answers) >= 7,
                   what="an answer")

    try:
        code = [run_until_done(argv, traffic)]
    finally:
        notifier.stop(timeout=1.0)
        raw.shutdown()
        master.disconnect()
    assert code == [0]
    ref = read_reference(truth)
    record = json.loads(out.read_text())
    assert record["truth_samples"] == len(ref.sync) and record["truth_samples"] + \
        record["truth_late"] == len(sent)
    # an answer sent over half a period late gets no truth: how many is the machine's
    assert set(ref.sync.tolist()) <= set(sent) and len(ref.sync) >= 1
    syncs = {bytes(m.data)[0]: m.timestamp for m in answers if m.arbitration_id == 0x080}
    for k, counter in enumerate(ref.sync.tolist()):
        assert ref.time_s[k] == pytest.approx(syncs[counter], abs=1e-6)  # the SYNC's time
    # step 0 is read at start, SYNC n (counter n) reads step n: every SYNC its own step
    steps = Simulator(load_scene("calibration"), seed=7).run(50).force_N[:, 0]
    for k, counter in enumerate(ref.sync.tolist()):
        np.testing.assert_array_equal(ref.force_N[k], steps[counter])
