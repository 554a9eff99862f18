"""Loss strategies exactly as docs/model.md §6 defines them, and blend's closed-form variance gain."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from agent.strategies import BlendParams, LinkMemory, state_width, substitute
from formation.errors import PluginError
from formation.plugin_api import NoParams

D = 2


def step(
    strategy,
    memory,
    arrived,
    received=None,
    estimate=None,
    has_estimate=None,
    v_prev=None,
    epoch=1,
    alpha=0.5,
):  # type: ignore[no-untyped-def]
    n = len(arrived)
    arrived = np.asarray(arrived, dtype=bool)
    received = np.zeros((n, D)) if received is None else np.asarray(received, dtype=float)
    estimate = np.zeros((n, D)) if estimate is None else np.asarray(estimate, dtype=float)
    has_estimate = (
        np.zeros(n, dtype=bool) if has_estimate is None else np.asarray(has_estimate, dtype=bool)
    )
    v_prev = np.zeros(D) if v_prev is None else np.asarray(v_prev, dtype=float)
    params = BlendParams(alpha=alpha) if strategy == "blend" else NoParams()
    width = state_width(strategy, D)
    if memory.state.shape[1] != width:  # a memory made without the strategy's state
        memory = replace(memory, state=np.zeros((n, width)))
    receivers = np.ones(n, dtype=np.int64)
    return substitute(
        strategy,
        params,
        epoch,
        arrived,
        received,
        memory,
        estimate,
        has_estimate,
        v_prev,
        1.0,
        receivers,
    )


def test_arrived_packets_are_used_as_received_by_every_strategy() -> None:
    for strategy in ("zero", "hold", "estimate", "blend", "drop"):
        sub, mem = step(strategy, LinkMemory.empty(1, D), [True], received=[[2.0, 3.0]])
        assert sub.used[0] and not sub.substituted[0]
        np.testing.assert_array_equal(sub.values[0], [2.0, 3.0])
        np.testing.assert_array_equal(mem.last[0], [2.0, 3.0])


def test_zero_substitutes_the_origin() -> None:
    sub, _ = step("zero", LinkMemory.empty(1, D), [False])
    assert sub.used[0] and sub.substituted[0]
    np.testing.assert_array_equal(sub.values[0], [0.0, 0.0])


def test_hold_uses_the_last_received_value_and_drops_before_the_first() -> None:
    mem = LinkMemory.empty(1, D)
    sub, mem = step("hold", mem, [False])
    assert not sub.used[0]  # nothing received yet: behaves as drop
    _, mem = step("hold", mem, [True], received=[[1.0, -1.0]])
    sub, _ = step("hold", mem, [False])
    assert sub.used[0]
    np.testing.assert_array_equal(sub.values[0], [1.0, -1.0])


def test_estimate_uses_the_leader_estimate_and_falls_back_to_hold_counted() -> None:
    _, mem = step("estimate", LinkMemory.empty(2, D), [True, False], received=[[1.0, 1.0], [0, 0]])
    sub, _ = step(
        "estimate",
        mem,
        [False, False],
        estimate=[[5.0, 5.0], [6.0, 6.0]],
        has_estimate=[True, False],
    )
    np.testing.assert_array_equal(sub.values[0], [5.0, 5.0])
    assert list(sub.fallback) == [False, True]
    assert list(sub.used) == [True, False]  # link 1 has no estimate and nothing to hold: dropped


def test_blend_filters_estimates_and_restarts_on_arrival() -> None:
    mem = LinkMemory.empty(1, D)
    _, mem = step("blend", mem, [True], received=[[0.0, 0.0]])
    sub, mem = step(
        "blend", mem, [False], estimate=[[1.0, 0.0]], has_estimate=[True], v_prev=[0.5, 0.0]
    )
    # b = α x̂ + (1 − α)(b_prev + T v_ref) = 0.5·1 + 0.5·(0 + 0.5)
    np.testing.assert_allclose(sub.values[0], [0.75, 0.0])
    sub, mem = step("blend", mem, [False], estimate=[[1.0, 0.0]], has_estimate=[True])
    np.testing.assert_allclose(sub.values[0], [0.875, 0.0])
    _, mem = step("blend", mem, [True], received=[[9.0, 9.0]])
    np.testing.assert_array_equal(mem.state[0], [9.0, 9.0])


def test_drop_leaves_the_term_out() -> None:
    sub, _ = step("drop", LinkMemory.empty(1, D), [False])
    assert not sub.used[0] and not sub.substituted[0]


def test_unknown_strategy_is_named() -> None:
    with pytest.raises(
        PluginError, match="loss strategy plug-in 'guess': no loss strategy is registered"
    ):
        step("guess", LinkMemory.empty(1, D), [False])


@pytest.mark.parametrize("alpha", [0.25, 0.5, 0.8])
def test_blend_variance_is_alpha_over_two_minus_alpha_of_estimate(alpha: float) -> None:
    """Fixed truth, unbiased estimates of known covariance: Var(blend) = α/(2−α) Var(estimate)."""
    rng = np.random.default_rng(7)
    truth = np.array([1.0, -2.0])
    steps, links, sigma = 400, 200, 0.1
    mem = LinkMemory.empty(links, D)
    _, mem = step(
        "blend", mem, np.ones(links, bool), received=np.tile(truth, (links, 1)), alpha=alpha
    )
    est_err, blend_err = [], []
    for k in range(steps):
        estimate = truth + sigma * rng.standard_normal((links, D))
        sub, mem = step("blend", mem, np.zeros(links, bool), estimate=estimate,
                        has_estimate=np.ones(links, bool), epoch=k + 2, alpha=alpha)  # fmt: skip
        if k >= 50:  # past the filter's transient from its exact start
            est_err.append(estimate - truth)
            blend_err.append(sub.values - truth)
    ratio = np.var(np.concatenate(blend_err)) / np.var(np.concatenate(est_err))
    assert ratio == pytest.approx(alpha / (2 - alpha), rel=0.10)
