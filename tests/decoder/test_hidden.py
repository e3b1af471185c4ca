"""--hidden auto: Eq. 21's candidates, pruning from 20 nodes, and what the model file keeps."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from decoder.hidden import eq21_candidates, remove_nodes, saliency
from decoder.lmmlp import LMMLPDecoder
from decoder.mlp import Layout, forward, nguyen_widrow
from decoder.registry import load_decoder

pytestmark = pytest.mark.blas  # floats through BLAS: CI runs it again on other kernels


def test_eq21_candidates() -> None:
    assert eq21_candidates(9, 9) == tuple(range(5, 15))  # the paper's Table 1 sizes
    assert eq21_candidates(27, 27) == tuple(range(8, 18))


def test_a_node_that_carries_nothing_is_removed_without_changing_the_outputs() -> None:
    layout = Layout(4, 6, 3)
    theta = nguyen_widrow(layout, np.random.default_rng(0))
    A1, _ = layout.unpack(theta)
    A1[2, :] = 0.0  # node 2: tanh(0) for every input, a constant
    A1[2, -1] = 0.3
    x = np.random.default_rng(1).uniform(-1, 1, (50, 4))
    s = saliency(layout, theta, x, None)
    assert s[2] < 1e-12 and np.all(np.delete(s, 2) > 1e-3)
    smaller, pruned = remove_nodes(layout, theta, [2], x)
    assert smaller.n_hidden == 5
    np.testing.assert_allclose(forward(smaller, pruned, x).y, forward(layout, theta, x).y,
                               atol=1e-12)


def test_auto_picks_the_papers_range_on_its_protocol_and_says_how(synth: Any,
                                                                   tmp_path: Path) -> None:
    """The paper's noise-free protocol, 1000 samples: pruning from 20 stops at 8..14."""
    r, f = synth(1000, seed=61, noise=False)
    decoder = LMMLPDecoder(hidden="auto").fit(r, f)
    choice = decoder.hidden_choice
    assert choice is not None and 8 <= choice.hidden <= 14 and decoder.hidden_ == choice.hidden
    assert choice.start == 20 and choice.steps[0].hidden == 20
    kept = [s.hidden for s in choice.steps if s.kept]
    assert kept == list(range(20, choice.hidden - 1, -1))
    assert choice.steps[-1].kept is False or choice.hidden == choice.candidates[0]
    assert "chose" in choice.describe()[-1]
    decoder.save(tmp_path / "auto.msgpack")
    loaded = load_decoder(tmp_path / "auto.msgpack")
    meta = loaded.meta()  # type: ignore[attr-defined]
    assert meta["hidden"]["chosen"] == choice.hidden
    np.testing.assert_array_equal(meta["hidden"]["curve"]["hidden"],
                                  [s.hidden for s in choice.steps])
    np.testing.assert_array_equal(meta["hidden"]["curve"]["val_mse"],
                                  [s.val_mse for s in choice.steps])
    assert meta["training"]["goal_units"] == "N"
    assert loaded.hidden == "auto" and loaded.hidden_ == choice.hidden  # type: ignore[attr-defined]
    np.testing.assert_array_equal(loaded.decode(r[:20]).force_N, decoder.decode(r[:20]).force_N)
