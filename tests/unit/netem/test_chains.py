"""Many links' chains: the compiled passes give the states and drops the numpy steps give."""

from __future__ import annotations

import numpy as np
import pytest

import netem.links.chains
from formation.linkmodels import GilbertElliott
from netem.links.chains import COMPILED_FROM, run_chain
from netem.links.layer import Keys
from netem.links.linkmodels import gilbert_elliott
from netem.links.linkmodels.gilbert_elliott import GilbertElliottLayer


def test_the_compiled_chains_give_the_numpy_states(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(3)
    links, epochs = COMPILED_FROM // 64, 64
    table = rng.integers(0, 3, (links, epochs, 3))
    s0 = rng.integers(0, 3, links)
    compiled = run_chain(table, s0)
    monkeypatch.setattr(netem.links.chains, "COMPILED_FROM", 1 << 62)
    np.testing.assert_array_equal(compiled, run_chain(table, s0))
    assert compiled[0].tolist() == run_chain(table[:1], s0[:1])[0].tolist()  # one link's loop


def test_one_link_s_long_chain_runs_compiled_with_the_loop_s_states(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A schedule of one link over ``COMPILED_FROM`` epochs is stepped compiled (its Python
    loop made an object per epoch), to the same states."""
    import netem.links.compiled_chain

    rng = np.random.default_rng(4)
    table = rng.integers(0, 4, (1, COMPILED_FROM, 4))
    s0 = np.array([2])
    calls = []
    step = netem.links.compiled_chain.step_chains
    monkeypatch.setattr(
        netem.links.compiled_chain, "step_chains", lambda *a: calls.append(1) or step(*a)
    )
    compiled = run_chain(table, s0)
    assert calls == [1]
    monkeypatch.setattr(netem.links.chains, "COMPILED_FROM", 1 << 62)
    np.testing.assert_array_equal(compiled, run_chain(table, s0))
    assert calls == [1]


def test_the_compiled_gilbert_elliott_layer_gives_the_table_steps(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    spec = GilbertElliott(model="gilbert_elliott", p=0.2, r=0.3, one_minus_h=0.7, one_minus_k=0.1)
    layer = GilbertElliottLayer(spec, 0)
    links = np.arange(COMPILED_FROM // 64, dtype=np.int64)[:, None]
    keys, epochs = Keys(5, links, links + 1), np.arange(64, dtype=np.int64)
    s0 = np.arange(links.shape[0]) % 2
    compiled, last = layer.run(keys, epochs, s0)
    monkeypatch.setattr(gilbert_elliott, "COMPILED_FROM", 1 << 62)
    steps, step_last = layer.run(keys, epochs, s0)
    np.testing.assert_array_equal(compiled.drop, steps.drop)
    np.testing.assert_array_equal(compiled.state, steps.state)
    np.testing.assert_array_equal(last, step_last)
    assert compiled.state.dtype == steps.state.dtype and compiled.drop.any() and (last == 1).any()
