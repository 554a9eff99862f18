"""Many links' chains: the compiled pass gives the states the numpy steps give."""

from __future__ import annotations

import numpy as np
import pytest

import netem.links.chains
from netem.links.chains import COMPILED_FROM, run_chain


def test_the_compiled_chains_give_the_numpy_states(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(3)
    links, epochs = COMPILED_FROM // 64, 64
    table = rng.integers(0, 3, (links, epochs, 3))
    s0 = rng.integers(0, 3, links)
    compiled = run_chain(table, s0)
    monkeypatch.setattr(netem.links.chains, "COMPILED_FROM", 1 << 62)
    np.testing.assert_array_equal(compiled, run_chain(table, s0))
    assert compiled[0].tolist() == run_chain(table[:1], s0[:1])[0].tolist()  # one link's loop
