"""The publisher's raw samples (canbus.master.rawsample): a raw subscriber gets, for every
published sample, the resistances the patch sent through its PDOs, before the host's scale
and decoder; NaN and MISSING where a PDO did not arrive, FAULTY where the patch's EMCY
masked the taxel, and a sample whose decoder failed too."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numpy.typing import NDArray

from canbus.master.hostconfig import HostConfig, PatchConfig
from canbus.master.rawsample import RawSample
from canbus.offline.decode import decode_recording
from decoder.protocol import Decoded
from decoder.reasons import Reason
from decoder.registry import create_decoder
from tests.support.rigs.dataplane import LSB, Host, load
from tests.support.rigs.recording import record

CODES = st.one_of(st.integers(0, 0xFFFF), st.sampled_from([0, 1, 0xFFFD, 0xFFFE, 0xFFFF]))


def _ohms(codes: NDArray[np.uint16]) -> NDArray[np.float64]:
    """What a code stands for (canbus.codes): LSB times it; open and saturated +inf."""
    return np.where(codes >= 0xFFFE, np.inf, codes.astype(np.float64) * LSB)


class Raw:
    """A data plane of two patches (tests.support.rigs.dataplane) with a raw subscriber."""

    def __init__(self, mode: str) -> None:
        self.host = Host(mode=mode)
        self.cycle = 0
        self.samples: list[RawSample] = []

    def reset(self) -> None:
        self.host.reset()  # channels anew: no mask, a scale of one
        self.samples = []
        self.host.plane.subscribe_raw(self.samples.extend)


@pytest.fixture(scope="module", params=["xyz", "z"])
def raw(request: pytest.FixtureRequest) -> Iterator[Raw]:
    made = Raw(request.param)
    yield made
    made.host.close()


@settings(max_examples=40)
@given(data=st.data())
def test_a_raw_subscriber_gets_what_the_patch_sent(raw: Raw, data: st.DataObject) -> None:
    raw.reset()
    host = raw.host
    a, b = host.patches
    pillars = a.node.pillars
    codes = data.draw(arrays(np.uint16, (2, 9, pillars), elements=CODES), label="codes")
    masked = data.draw(arrays(np.bool_, 9), label="masked")
    host.plane.channel(1).masked[:] = masked
    host.plane.channel(1).scale = np.full((9, 1), 1.25)  # what the decoder gets, not them
    raw.cycle += 1
    frames = []
    for patch, sent in zip((a, b), codes, strict=True):
        patch.node.codes[:, :pillars] = sent
        frames.append(patch.answer(patch.codec.pack(patch.node.values())[0], raw.cycle))
    sent_of_a = data.draw(st.integers(0, len(frames[0])), label="a's frames sent")
    host.sync(raw.cycle)
    host.feed(frames[0][:sent_of_a] + frames[1])  # a's answer cut short
    host.sync(raw.cycle + 1)  # closes the cycle: an incomplete answer is published too
    host.plane.publish_pending()
    got = {s.patch: s for s in raw.samples}
    assert sorted(got) == [1, 2] and len(raw.samples) == 2
    missing = np.zeros(9, dtype=bool)
    for place in range(sent_of_a, len(frames[0])):
        missing[a.carried(place)] = True
    for node, sent, lost, mask in ((1, codes[0], missing, masked),
                                   (2, codes[1], np.zeros(9, bool), np.zeros(9, bool))):
        sample = got[node]
        assert (sample.cycle, sample.sync_counter) == (raw.cycle, raw.cycle % 240 + 1)
        assert sample.complete == (not lost.any())
        np.testing.assert_array_equal(sample.resistance_ohm[~lost], _ohms(sent)[~lost])
        assert np.isnan(sample.resistance_ohm[lost]).all()
        expected = np.where(mask, Reason.FAULTY, np.where(lost, Reason.MISSING, Reason.OK))
        assert sample.reason.tolist() == expected.tolist()
        assert sample.valid.tolist() == (~mask & ~lost).tolist()


class Failing:
    """A decoder that fails on every sample."""

    def decode(self, resistance_ohm: NDArray[np.float64]) -> Decoded:
        raise ArithmeticError("no forces today")


def test_a_sample_whose_decoder_fails_still_reaches_the_raw_subscribers() -> None:
    host = Host(Failing())
    try:
        samples: list[RawSample] = []
        host.plane.subscribe_raw(samples.extend)
        host.sync(1)
        a, b = host.patches
        host.feed(a.frames(load(), 1) + b.frames(load(0.5), 1))
        host.plane.publish_pending()
        assert host.out == [] and host.plane.stats.decode_errors == 2
        assert [(s.patch, s.cycle, s.complete) for s in samples] == [(1, 1, True), (2, 1, True)]
        for sample, patch in zip(samples, host.patches, strict=True):
            np.testing.assert_array_equal(sample.resistance_ohm,
                                          _ohms(patch.node.codes[:, :patch.node.pillars]))
    finally:
        host.close()


def test_a_raw_subscriber_that_fails_is_counted_and_the_others_still_get_the_batch(
        host: Host) -> None:
    got: list[RawSample] = []

    def broken(samples: list[RawSample]) -> None:
        raise RuntimeError("subscriber bug")

    host.plane.subscribe_raw(broken)
    host.plane.subscribe_raw(got.extend)
    host.sync(1)
    a, b = host.patches
    host.feed(a.frames(load(), 1) + b.frames(load(), 1))
    host.plane.publish_pending()
    assert [s.patch for s in got] == [1, 2] and len(host.out) == 2
    assert host.plane.stats.callback_errors == 1
    host.plane.unsubscribe_raw(got.extend)
    host.sync(2)
    host.feed(a.frames(load(), 2) + b.frames(load(), 2))
    host.plane.publish_pending()
    assert len(got) == 2 and len(host.out) == 4


def test_a_decoded_recording_s_raw_samples_are_its_force_frames_before_the_decoder(
        tmp_path: Path) -> None:
    """Through the host (``HostManager.on_raw_samples``): one raw sample per force frame,
    the same patch, cycle and completeness, and the frame's forces are what the config's
    decoder makes of the raw sample's resistances."""
    log, _ = record(tmp_path, "raw-samples", cycles=20, seed=7, nodes=(1, 2))
    config = HostConfig(patches=(PatchConfig(1), PatchConfig(2)), listen_only=True,
                        scan=False)
    samples: list[RawSample] = []
    frames = decode_recording(log, config, on_raw=samples.extend)
    assert len(frames) > 40
    assert [(s.patch, s.cycle, s.complete) for s in samples] == \
        [(f.patch, f.cycle, f.complete) for f in frames]
    decoder = create_decoder("analytic")
    for sample, frame in zip(samples, frames, strict=True):
        if not sample.complete:
            continue
        decoded = decoder.decode(sample.resistance_ohm[None])
        np.testing.assert_array_equal(frame.force_N, np.where(
            decoded.valid[0][:, None], decoded.force_N[0], 0.0))
