"""One contract for every registered decoder: fit, decode, masks, no NaN, save/load round trip."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from decoder.protocol import Decoded, Decoder
from decoder.registry import available_decoders, create_decoder, decoder_class, load_decoder
from skin.errors import ConfigError, DecodeError, NotFittedError

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels

FAST = {"lm-mlp": {"hidden": 10, "max_epochs": 40}, "hybrid": {"max_epochs": 40}}
UNTRAINED = ("analytic", "eq9")  # no fit: they decode from the sensor constants alone


def _make(name: str) -> Decoder:
    return create_decoder(name, **FAST.get(name, {}))


def _check(out: Decoded, n: int) -> None:
    assert out.force_N.shape == (n, 9, 3) and out.force_N.dtype == np.float64
    assert out.valid.shape == (n, 9) and out.reason.dtype == np.uint8
    assert np.all(np.isfinite(out.force_N))
    np.testing.assert_array_equal(out.valid, out.reason == 0)
    assert not out.force_N[~out.valid].any()


@pytest.mark.parametrize("name", available_decoders())
@pytest.mark.parametrize("data", ["paper_data", "xyz_data"])
def test_contract(name: str, data: str, request: pytest.FixtureRequest, tmp_path: Path) -> None:
    r_train, f_train, r_test, f_test = request.getfixturevalue(data)
    decoder = _make(name)
    assert decoder.fit(r_train, f_train) is decoder
    out = decoder.decode(r_test)
    _check(out, r_test.shape[0])
    # On its own scene a trained decoder refuses few taxels (lm-mlp's checks are calibrated
    # on held-out rows to flag about 1 %; the promise is at most 5 %).
    assert out.valid.mean() >= 0.95
    rms = np.sqrt(np.mean(f_test**2))
    assert np.sqrt(np.mean((out.force_N - f_test) ** 2)) < 0.5 * rms  # a real decoder
    path = tmp_path / f"{name}.msgpack"
    decoder.save(path)
    for loaded in (load_decoder(path), type(decoder).load(path)):
        np.testing.assert_array_equal(loaded.decode(r_test).force_N, out.force_N)
    bad = r_test.copy()
    bad[:, 4, 0] = np.nan
    bad[0, 0, 0] = np.inf
    bad[1, 1, 0] = 0.0
    masked = decoder.decode(bad)
    _check(masked, bad.shape[0])
    assert not masked.valid[:, 4].any()
    assert masked.valid[2:, [0, 1, 2, 3, 5, 6, 7, 8]].all()


@pytest.mark.parametrize("name", [n for n in available_decoders() if n not in UNTRAINED])
def test_unfitted_use_raises_not_fitted(name: str, tmp_path: Path) -> None:
    decoder = _make(name)
    with pytest.raises(NotFittedError):
        decoder.decode(np.full((1, 9, 1), 1000.0))
    with pytest.raises(ValueError, match="not fitted"):
        decoder.save(tmp_path / "m.msgpack")


def test_wrong_pillar_count_and_shape_are_refused(paper_data: Any) -> None:
    decoder = create_decoder("deconv").fit(paper_data[0], paper_data[1])
    with pytest.raises(DecodeError, match="1-pillar"):
        decoder.decode(np.full((2, 9, 3), 1000.0))
    with pytest.raises(DecodeError, match="shape"):
        decoder.decode(np.full((2, 8, 1), 1000.0))


def test_registry_knows_builtins_and_refuses_unknown_names() -> None:
    assert available_decoders()[:4] == ("analytic", "deconv", "lm-mlp", "hybrid")
    assert decoder_class("analytic").name == "analytic"
    with pytest.raises(ConfigError, match="unknown decoder"):
        decoder_class("nope")


def test_entry_points_extend_the_registry(monkeypatch: pytest.MonkeyPatch) -> None:
    from importlib.metadata import EntryPoint

    import decoder.registry as registry

    ep = EntryPoint("mine", "decoder.analytic:AnalyticDecoder", registry.ENTRY_POINT_GROUP)
    monkeypatch.setattr(registry, "entry_points", lambda group: [ep])
    registry.refresh()  # the entry points are read once: read them again
    try:
        assert "mine" in available_decoders()
        assert decoder_class("mine").name == "analytic"
    finally:
        monkeypatch.undo()
        registry.refresh()
    assert "mine" not in available_decoders()


def test_the_registry_reads_entry_points_once(monkeypatch: pytest.MonkeyPatch) -> None:
    import decoder.registry as registry

    reads = []
    real = registry.entry_points
    monkeypatch.setattr(registry, "entry_points", lambda group: reads.append(group) or real(
        group=group))
    registry.refresh()
    try:
        for name in available_decoders():
            create_decoder(name)
            assert decoder_class(name) is decoder_class(name)
        assert reads == [registry.ENTRY_POINT_GROUP]
    finally:
        monkeypatch.undo()
        registry.refresh()


@pytest.mark.parametrize("name", available_decoders())
def test_needs_fitting_says_whether_a_fresh_decoder_decodes(name: str) -> None:
    """The class-level fact agrees with what a fresh decoder does."""
    cls = decoder_class(name)
    assert cls.needs_fitting == (name not in UNTRAINED)
    rest = np.full((1, 9, 1), 1000.0)
    if cls.needs_fitting:
        with pytest.raises(NotFittedError):
            _make(name).decode(rest)
    else:
        _check(_make(name).decode(rest), 1)
