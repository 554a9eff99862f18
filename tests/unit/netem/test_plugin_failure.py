"""A link model plug-in that fails mid-run: netem decides every epoch before the failure, and
the failure surfaces at the epoch it belongs to, not when the block holding it is planned."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from formation.errors import PluginFailure
from formation.linkmodels import Bernoulli, LinkModelSpec, spec_class
from netem.links.models import LinkModel

BAD = Path(__file__).resolve().parents[2] / "data" / "plugins"


@pytest.fixture
def explodes() -> Iterator[LinkModelSpec]:
    sys.path.insert(0, str(BAD))
    yield spec_class("bad_plugins:Explodes")(at_epoch=12)
    sys.path.remove(str(BAD))


def test_the_epochs_before_the_failure_are_decided_and_it_is_raised_at_its_epoch(
    explodes: LinkModelSpec,
) -> None:
    lossy = Bernoulli(p_loss=0.3)
    failing = LinkModel([lossy, explodes], seed=7, src=1, dst=2)  # blocks of 1,024 epochs
    failing.prepare(0)  # planning the block ahead does not fail
    plain = LinkModel([lossy], seed=7, src=1, dst=2)
    verdicts = [failing.decide(k).verdict for k in range(12)]
    assert verdicts == [plain.decide(k).verdict for k in range(12)]
    assert "drop" in verdicts and "pass" in verdicts
    codes, table = failing.coded(0, 20)
    assert [table[c] is None for c in codes] == [False] * 12 + [True] * 8  # never clean
    with pytest.raises(PluginFailure, match=r"failed at epoch 12 \(link 1->2\): raised ValueError"):
        failing.decide(12)
    with pytest.raises(PluginFailure, match=r"failed at epoch 12 "):
        failing.decide(30)


def test_a_delay_that_turns_nan_fails_at_its_epoch() -> None:
    sys.path.insert(0, str(BAD))
    try:
        spec = spec_class("bad_plugins:NanDelay")(at_epoch=12)
    finally:
        sys.path.remove(str(BAD))
    model = LinkModel([spec], seed=7, src=1, dst=2)
    assert [model.decide(k).verdict for k in range(12)] == ["pass"] * 12
    with pytest.raises(PluginFailure, match=r"failed at epoch 12 .*delay_ms is not finite"):
        model.decide(12)
