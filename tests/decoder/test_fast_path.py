"""The fast path (every reading decodable: no masks, no reasons) against the full path.

Every decoder answers through ``_decode_fast`` when no taxel needs masking and
through ``_decode_full`` otherwise. These tests feed random mixes of good and
bad readings (NaN, ±inf, <= 0, open, short, saturated, near zero, near full
scale, out of range) and check that the fast path answers exactly when the
full path masks nothing, and then with the same bits; so it can never hide a
bad reading or drift from the full path.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from decoder.protocol import BaseDecoder, Decoded, masked
from decoder.reasons import Reason, saturation_ohm
from decoder.registry import create_decoder
from decoder.tripod3 import TripodInverse
from skin.constants import DEFAULT_CONSTANTS

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels

SAT = saturation_ohm(DEFAULT_CONSTANTS)
LSB = DEFAULT_CONSTANTS.resistance_lsb_ohm
BAD = (np.nan, np.inf, -np.inf, -5.0, -0.0, 0.0, 5e-324, 1e-300, LSB, SAT, SAT - LSB, SAT + 1.0,
       1e308, -1e308, 0.3, 1.6, 0.6, 1.5, 0.65, 1.43)
"""Bad or edge readings; values below 2 are multiples of the pillar's R0 (plausible, some
out of range), the rest are ohm."""
APART = np.array([0.65, 1.43, 1.43])
"""A taxel's (z, x, y) ratios, each within the strain limit, whose lengths cannot meet."""
QUICK = {"lm-mlp": {"hidden": 6, "max_epochs": 3}, "hybrid": {"hidden": 4, "max_epochs": 3}}
NAMES = ("analytic", "deconv", "lm-mlp", "hybrid", "eq9")


@pytest.fixture(scope="module")
def fitted(paper_data: Any, xyz_data: Any) -> dict[tuple[str, int], tuple[BaseDecoder, Any]]:
    """Every decoder fitted in both modes (quickly: only the paths matter here)."""
    out: dict[tuple[str, int], tuple[BaseDecoder, Any]] = {}
    for pillars, data in ((1, paper_data), (3, xyz_data)):
        for name in NAMES:
            decoder = create_decoder(name, **QUICK.get(name, {}))
            assert isinstance(decoder, BaseDecoder)
            out[name, pillars] = (decoder.fit(data[0], data[1]), data[2])
    return out


def _same(a: Decoded, b: Decoded) -> None:
    for field in ("force_N", "valid", "reason"):
        x, y = getattr(a, field), getattr(b, field)
        assert x.dtype == y.dtype and x.shape == y.shape
        np.testing.assert_array_equal(x, y, strict=True)
    # Same bits, so +0.0 and -0.0 are told apart too.
    assert a.force_N.tobytes() == b.force_N.tobytes()


def _check_paths(decoder: BaseDecoder, r: np.ndarray) -> Decoded:
    force, reason = decoder._decode_full(r)
    fast = decoder._decode_fast(r)
    assert (fast is None) == bool(reason.any())  # answers exactly when nothing is masked
    if fast is not None:
        assert fast.shape == force.shape and fast.tobytes() == force.tobytes()
    out = decoder.decode(r)
    _same(out, masked(force, reason, r.shape[:1]))
    assert np.all(np.isfinite(out.force_N)) and not out.force_N[~out.valid].any()
    np.testing.assert_array_equal(out.valid, out.reason == 0)
    patches = decoder.decode(r[:, None])  # (samples, patches, 9, P) gives the same bits
    _same(patches, Decoded(out.force_N[:, None], out.valid[:, None], out.reason[:, None]))
    return out


def _readings(data: st.DataObject, pool: np.ndarray, samples: int, bad_share: float) -> np.ndarray:
    """Rows drawn from a pool of good readings, with some readings replaced by bad ones."""
    rows = data.draw(st.lists(st.integers(0, pool.shape[0] - 1), min_size=samples,
                              max_size=samples))
    r = pool[rows].copy()
    r0 = DEFAULT_CONSTANTS.nominal_resistance_ohm[: r.shape[-1]]
    flat, scale = r.reshape(-1), np.broadcast_to(r0, r.shape).reshape(-1)
    for i in range(flat.size):
        if data.draw(st.floats(0.0, 1.0)) < bad_share:
            value = data.draw(st.sampled_from(BAD))
            flat[i] = value * scale[i] if 0.0 < value < 2.0 else value
    if r.shape[-1] == 3 and bad_share and data.draw(st.booleans()):
        taxel = data.draw(st.integers(0, samples * 9 - 1))
        r.reshape(-1, 3)[taxel] = APART * r0
    return r


@pytest.mark.parametrize("pillars", [1, 3])
@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_fast_and_full_paths_agree_on_any_mix(fitted: Any, name: str, pillars: int,
                                              data: st.DataObject) -> None:
    decoder, pool = fitted[name, pillars]
    samples = data.draw(st.sampled_from([1, 1, 2, 3, 8, 12]))
    bad_share = data.draw(st.sampled_from([0.0, 0.0, 0.02, 0.1, 0.5]))
    _check_paths(decoder, _readings(data, pool, samples, bad_share))


@pytest.mark.parametrize("pillars", [1, 3])
@pytest.mark.parametrize("name", NAMES)
def test_every_single_bad_reading_leaves_the_fast_path(fitted: Any, name: str,
                                                       pillars: int) -> None:
    decoder, pool = fitted[name, pillars]
    good = pool[:1].copy()
    assert decoder._decode_fast(good) is not None
    r0 = DEFAULT_CONSTANTS.nominal_resistance_ohm[:pillars]
    for taxel in range(9):
        for pillar in range(pillars):
            for value in BAD:
                r = good.copy()
                r[0, taxel, pillar] = value * r0[pillar] if 0.0 < value < 2.0 else value
                out = _check_paths(decoder, r)
                if not (0.0 < value < 2.0) or value in (0.3, 1.6):
                    assert not out.valid[0, taxel], (taxel, pillar, value)


@pytest.mark.parametrize("pillars", [1, 3])
@pytest.mark.parametrize("name", NAMES)
def test_batches_across_chunks_agree(fitted: Any, name: str, pillars: int) -> None:
    decoder, pool = fitted[name, pillars]
    pool = pool[decoder.decode(pool).valid.all(axis=1)]  # lm-mlp refuses about 1 % at home
    rng = np.random.default_rng(pillars)
    r = pool[rng.integers(0, pool.shape[0], 2100)]
    assert decoder._decode_fast(r) is not None
    flat = r.reshape(-1)
    for i in (0, 1819 * 9 * pillars, 1820 * 9 * pillars, 910 * 9 * pillars - 1, flat.size - 1):
        flat[i] = np.nan
    flat[rng.integers(0, flat.size, 20)] = SAT
    _check_paths(decoder, r)


@pytest.mark.parametrize("pillars", [1, 3])
@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_analytic_decodes_each_sample_as_in_any_batch(fitted: Any, pillars: int,
                                                      data: st.DataObject) -> None:
    """Elementwise arithmetic: one sample (Python floats in 3-axis mode), a few (taxel-major
    numpy) and many (pillar-major chunks) give the same bits."""
    decoder, pool = fitted["analytic", pillars]
    samples = data.draw(st.sampled_from([2, 5, 9, 30]))
    r = _readings(data, pool, samples, data.draw(st.sampled_from([0.0, 0.05])))
    batch = decoder.decode(r)
    for i in range(samples):
        one = decoder.decode(r[i:i + 1])
        _same(one, Decoded(batch.force_N[i:i + 1], batch.valid[i:i + 1], batch.reason[i:i + 1]))


@pytest.mark.parametrize("samples", [1, 2, 8, 100])
def test_lengths_that_cannot_meet_are_masked_on_every_path(fitted: Any, samples: int) -> None:
    for name in ("analytic", "deconv", "hybrid"):
        decoder, pool = fitted[name, 3]
        r = pool[:samples].copy()
        r[-1, 4] = APART * DEFAULT_CONSTANTS.nominal_resistance_ohm
        out = _check_paths(decoder, r)
        assert out.reason[-1, 4] == Reason.OUT_OF_RANGE and out.valid.sum() == 9 * samples - 1


def test_scalar_tripod_matches_numpy_tripod_bit_for_bit() -> None:
    rng = np.random.default_rng(7)
    r0 = DEFAULT_CONSTANTS.nominal_resistance_ohm * rng.uniform(0.9, 1.1, (9, 3))
    inverse = TripodInverse(DEFAULT_CONSTANTS, r0, SAT)
    r = r0 * rng.uniform(0.75, 1.3, (400, 9, 3))
    batch, ok = inverse.full(r)
    for i in range(r.shape[0]):
        one = inverse.fast(r[i:i + 1])
        assert (one is not None) == bool(ok[i].all())
        if one is not None:
            assert one.tobytes() == batch[i:i + 1].tobytes()


@pytest.mark.parametrize("samples", [1, 2, 100])
@pytest.mark.parametrize("pillars", [1, 3])
def test_saturation_inside_the_range_is_checked_on_both_paths(pillars: int, samples: int) -> None:
    """With R0 so high that full scale is reachable, a saturated reading still leaves the
    fast path (the default constants cannot reach it)."""
    r0 = np.full(pillars, SAT / 1.1)
    decoder = create_decoder("analytic", r0_ohm=r0)
    assert isinstance(decoder, BaseDecoder)
    good = np.full((samples, 9, pillars), SAT / 1.1 * 0.98)
    assert decoder._decode_fast(good) is not None
    bad = good.copy()
    bad[-1, 3, -1] = SAT
    out = _check_paths(decoder, bad)
    assert out.reason[-1, 3] == Reason.SATURATED and out.valid.sum() == 9 * samples - 1


@pytest.mark.parametrize("pillars", [1, 3])
def test_empty_batches_decode_to_empty_results(fitted: Any, pillars: int) -> None:
    for name in NAMES:
        decoder, _ = fitted[name, pillars]
        for lead in ((0,), (0, 2)):
            out = decoder.decode(np.zeros((*lead, 9, pillars)))
            assert out.force_N.shape == (*lead, 9, 3) and out.valid.shape == (*lead, 9)
            assert out.reason.shape == (*lead, 9) and out.reason.dtype == np.uint8
