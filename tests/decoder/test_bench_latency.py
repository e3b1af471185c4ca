"""Latency benchmarks (pytest-benchmark): one patch-sample through each decoder, both modes.

Run with -n 0 --benchmark-enable to measure (docs/decoders.md quotes the medians)::

    pytest tests/decoder/test_bench_latency.py -n 0 --benchmark-enable \
        --benchmark-columns=min,median

In the normal suite each runs once, unmeasured. The sample is a (1, 9, P) array
of ordinary readings, so it takes the fast path (asserted).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from decoder.protocol import BaseDecoder
from decoder.registry import create_decoder

NAMES = ("analytic", "deconv", "lm-mlp", "hybrid", "eq9")
FEW_EPOCHS = {"lm-mlp": {"max_epochs": 5}, "hybrid": {"max_epochs": 5}}  # sizes as in bench


@pytest.fixture(scope="module")
def fitted(paper_data: Any, xyz_data: Any) -> dict[tuple[str, int], tuple[BaseDecoder, Any]]:
    out: dict[tuple[str, int], tuple[BaseDecoder, Any]] = {}
    for pillars, data in ((1, paper_data), (3, xyz_data)):
        for name in NAMES:
            decoder = create_decoder(name, **FEW_EPOCHS.get(name, {}))
            assert isinstance(decoder, BaseDecoder)
            out[name, pillars] = (decoder.fit(data[0], data[1]), data[2])
    return out


@pytest.mark.parametrize("pillars", [1, 3])
@pytest.mark.parametrize("name", NAMES)
def test_bench_one_patch_sample(benchmark: Any, fitted: Any, name: str, pillars: int) -> None:
    decoder, test = fitted[name, pillars]
    one = np.ascontiguousarray(test[:1])
    assert decoder._decode_fast(one) is not None
    with threadpool_limits(1, user_api="blas"):  # as `skin bench` does
        out = benchmark(decoder.decode, one)
    assert out.force_N.shape == (1, 9, 3) and out.valid.all()
