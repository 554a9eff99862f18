"""Distance link models (range, logistic, log_distance): closed forms, measured rates, equalities.

Statistics: each model runs 50,000 epochs at each of four distances (200,000 decisions per
model) on one link, through ``LinkModel.schedule`` with the link's length given. A measured
delivery rate passes when it lies within ``Z = 4`` standard errors of the closed form
``expected_delivery_at``; the standard error comes from 50 batch means, which also holds
for correlated shadowing (runs of a few epochs, batches of 1,000). ``test_ci_rejects_*``
show the same intervals reject a model whose ``d50`` is off by 10 %.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest
from scipy.stats import norm

from formation.errors import TestbedError
from formation.linkmodels import Bernoulli, Delay, LinkModelSpec, LogDistance, Logistic, Range
from netem.links.matrix import delivery_plan
from netem.links.models import (
    LinkModel,
    delivery_matrix,
    expected_delivery_at,
    expected_loss_rate,
    link_lengths,
)

Z = 4.0
N_BATCHES = 50
N_EPOCHS = 50_000  # per distance
DISTANCES = (6.0, 9.0, 10.0, 12.0)  # [m], around d50 = 10 m

LOGISTIC = Logistic(d50_m=10.0, width_m=1.5)
# margin 0 at d50 = d0 10^((P_t - PL(d0) - S) / (10 n)) = 10 m: P_t 0, PL(d0) 40, n 3, S -70
LOG_DISTANCE = LogDistance(path_loss_d0_db=40.0, n=3.0, sigma_db=4.0, sensitivity_dbm=-70.0)
LOG_DISTANCE_CORR = LOG_DISTANCE.model_copy(update={"shadowing_correlation": 0.8})
RANGE = Range(max_range_m=10.0)


def measured(
    spec: LinkModelSpec | list[LinkModelSpec], d: float, seed: int
) -> npt.NDArray[np.bool_]:
    stack = spec if isinstance(spec, list) else [spec]
    model = LinkModel(stack, seed, 1, 2)
    return model.schedule(N_EPOCHS, distances_m=np.full(N_EPOCHS, d)).delivered


def interval(x: npt.NDArray[np.bool_]) -> tuple[float, float]:
    """Mean and its batch-means standard error."""
    b = x.astype(np.float64).reshape(N_BATCHES, -1).mean(axis=1)
    return float(b.mean()), float(b.std(ddof=1) / math.sqrt(N_BATCHES))


def within(spec: LinkModelSpec, truth: LinkModelSpec, seed: int) -> list[bool]:
    """Per distance: is the rate measured from ``spec`` within Z SE of ``truth``'s closed form?"""
    out = []
    for d in DISTANCES:
        rate, se = interval(measured(spec, d, seed))
        expected = float(expected_delivery_at(truth, d))
        # a rate of exactly 0 or 1 has SE 0: allow one decision's worth
        out.append(abs(rate - expected) <= Z * max(se, 1.0 / N_EPOCHS))
    return out


def test_closed_forms_are_the_textbook_ones() -> None:
    d = np.array([0.0, 5.0, 10.0, 20.0])
    assert expected_delivery_at(RANGE, d).tolist() == [1.0, 1.0, 1.0, 0.0]
    prr = 1.0 / (1.0 + np.exp((d - 10.0) / 1.5))
    np.testing.assert_allclose(expected_delivery_at(LOGISTIC, d), prr, rtol=1e-12)
    assert float(expected_delivery_at(LOGISTIC, 10.0)) == 0.5
    # log_distance: Φ(m / σ), m = 0 - 40 - 30 log10(max(d, 1) / 1) + 70
    m = 30.0 - 30.0 * np.log10(np.maximum(d, 1.0))
    np.testing.assert_allclose(expected_delivery_at(LOG_DISTANCE, d), norm.cdf(m / 4.0), rtol=1e-12)
    assert float(expected_delivery_at(LOG_DISTANCE, 10.0)) == pytest.approx(0.5, abs=1e-12)
    no_shadow = LOG_DISTANCE.model_copy(update={"sigma_db": 0.0})
    assert expected_delivery_at(no_shadow, d).tolist() == [1.0, 1.0, 1.0, 0.0]
    # stacked with another model: independent, so the rates multiply
    stacked = [LOGISTIC, Bernoulli(p_loss=0.2)]
    np.testing.assert_allclose(expected_delivery_at(stacked, d), 0.8 * prr, rtol=1e-12)
    with pytest.raises(
        TestbedError, match="logistic depends on distance; use expected_delivery_at"
    ):
        expected_loss_rate(LOGISTIC)


@pytest.mark.parametrize(
    "spec",
    [RANGE, LOGISTIC, LOG_DISTANCE, LOG_DISTANCE_CORR, [LOGISTIC, Bernoulli(p_loss=0.2)]],
    ids=["range", "logistic", "log_distance", "log_distance_correlated", "logistic+bernoulli"],
)
def test_measured_delivery_matches_closed_form(
    spec: LinkModelSpec | list[LinkModelSpec], seed: int
) -> None:
    for d in DISTANCES:
        rate, se = interval(measured(spec, d, seed))
        expected = float(expected_delivery_at(spec, d))
        assert abs(rate - expected) <= Z * max(se, 1.0 / N_EPOCHS), (d, rate, expected, se)


def _d50_off(spec: LinkModelSpec, factor: float) -> LinkModelSpec:
    if isinstance(spec, Logistic):
        return spec.model_copy(update={"d50_m": spec.d50_m * factor})
    if isinstance(spec, Range):
        return spec.model_copy(update={"max_range_m": spec.max_range_m * factor})
    assert isinstance(spec, LogDistance)  # d50 scales by factor when S drops by 10 n log10(factor)
    return spec.model_copy(
        update={"sensitivity_dbm": spec.sensitivity_dbm - 10 * spec.n * math.log10(factor)}
    )


@pytest.mark.parametrize(
    "spec",
    [LOGISTIC, LOG_DISTANCE, LOG_DISTANCE_CORR],
    ids=["logistic", "log_distance", "log_distance_correlated"],
)
@pytest.mark.parametrize("factor", [0.9, 1.1])
def test_ci_rejects_d50_off_by_ten_percent(spec: LinkModelSpec, factor: float, seed: int) -> None:
    wrong = _d50_off(spec, factor)
    assert all(within(spec, spec, seed))
    assert not all(within(wrong, spec, seed))


def test_ci_rejects_range_off_by_ten_percent(seed: int) -> None:
    # at 10 m (inside) and 10.5 m: a cutoff of 9 m or 11 m gets one of them wrong
    for factor, d in ((0.9, 9.5), (1.1, 10.5)):
        wrong = _d50_off(RANGE, factor)
        rate, _ = interval(measured(wrong, d, seed))
        assert rate != float(expected_delivery_at(RANGE, d))


def test_correlated_shadowing_loses_in_runs(seed: int) -> None:
    def runs(spec: LinkModelSpec) -> float:
        lost = ~measured(spec, 10.0, seed)
        starts = lost[1:] & ~lost[:-1]
        return float(lost.sum() / max(1, starts.sum()))

    assert runs(LOG_DISTANCE_CORR) > 2.0 * runs(LOG_DISTANCE)


# ----------------------------------------------------------------------------- equalities


STACKS: list[list[LinkModelSpec]] = [
    [LOGISTIC],
    [Bernoulli(p_loss=0.3), LOGISTIC],
    [LOGISTIC, Bernoulli(p_loss=0.3)],
    [LOG_DISTANCE_CORR, Delay(epochs=1, jitter_epochs=1)],
    [RANGE, LOG_DISTANCE],
]


@pytest.mark.parametrize("stack", STACKS, ids=lambda s: "+".join(x.model for x in s))
def test_decide_schedule_and_plan_agree(stack: list[LinkModelSpec], seed: int) -> None:
    n = 3000  # crosses block boundaries (1024)
    rng = np.random.default_rng(seed)
    dist = rng.uniform(4.0, 16.0, size=(n, 3))
    links = np.array([[1, 2], [2, 1], [3, 1]])
    plan = delivery_plan([stack] * 3, seed, links, n)
    matrix = plan.matrix(dist)
    assert np.array_equal(
        matrix.delivered, delivery_matrix([stack] * 3, seed, links, n, distances_m=dist).delivered
    )
    for col, (a, b) in enumerate(links.tolist()):
        model = LinkModel(stack, seed, a, b, block_epochs=1024)
        sched = model.schedule(n, distances_m=dist[:, col])
        assert np.array_equal(sched.delivered, matrix.delivered[:, col])
        assert np.array_equal(sched.delay_epochs, matrix.delay_epochs[:, col])
        got = [model.decide(k, distance_m=float(dist[k, col])) for k in range(n)]
        assert [o.delivered for o in got] == matrix.delivered[:, col].tolist()
        assert [o.copies for o in got] == matrix.copies[:, col].tolist()
        assert [o.delay_epochs for o in got] == matrix.delay_epochs[:, col].tolist()
        assert [sched.decision(k) for k in range(n)] == got
    for k in (0, 1023, 1024, n - 1):
        delivered, copies, delays = plan.at(k, dist[k])
        assert delivered.tolist() == matrix.delivered[k].tolist()
        assert copies.tolist() == matrix.copies[k].tolist()
        assert delays.tolist() == matrix.delay_epochs[k].tolist()


def test_the_first_dropping_model_is_named_in_stack_order(seed: int) -> None:
    far = 100.0  # logistic always drops
    first = LinkModel([Bernoulli(p_loss=1.0), LOGISTIC], seed, 1, 2).decide(5, distance_m=far)
    assert (first.delivered, first.model) == (False, "bernoulli")
    second = LinkModel([LOGISTIC, Bernoulli(p_loss=1.0)], seed, 1, 2).decide(5, distance_m=far)
    assert (second.delivered, second.model) == (False, "logistic")
    near = LinkModel([RANGE], seed, 1, 2)
    assert near.decide(5, distance_m=10.0).verdict == "pass"
    assert near.decide(5, distance_m=10.000001).model == "range"
    assert near.decide(5, seq=2, distance_m=10.000001).model == "range"


def test_a_distance_model_needs_the_distance(seed: int) -> None:
    model = LinkModel([Bernoulli(p_loss=0.1), LOGISTIC], seed, 1, 2)
    assert model.ranged
    with pytest.raises(TestbedError, match=r"1→2: stack\[1\] logistic decides by distance"):
        model.decide(3)
    with pytest.raises(TestbedError, match=r"stack\[1\] logistic decides by distance"):
        model.schedule(10)
    with pytest.raises(TestbedError, match="pass distances_m"):
        delivery_matrix([[LOGISTIC]], seed, [[1, 2]], 10)
    with pytest.raises(TestbedError, match=r"distances_m has shape \(10, 2\); expected \(10, 1\)"):
        delivery_matrix([[LOGISTIC]], seed, [[1, 2]], 10, distances_m=np.zeros((10, 2)))
    codes, table = model.coded(0, 10)
    assert all(table[c] is None for c in codes.tolist())  # never taken as clean
    assert not LinkModel([Bernoulli(p_loss=0.1)], seed, 1, 2).ranged


def test_shadowing_state_carries_over_a_replaced_stack(seed: int) -> None:
    d = np.full(400, 10.0)
    whole = LinkModel([LOG_DISTANCE_CORR], seed, 1, 2).schedule(400, distances_m=d).delivered
    changed = LinkModel([LOG_DISTANCE_CORR], seed, 1, 2)
    changed.replace([LOG_DISTANCE_CORR, Bernoulli(p_loss=0.0)], from_epoch=200)
    assert np.array_equal(changed.schedule(400, distances_m=d).delivered, whole)


def test_link_lengths_one_row_equals_many() -> None:
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    many = link_lengths(a, b)
    assert [float(link_lengths(a[i : i + 1], b[i : i + 1])[0]) for i in range(50)] == many.tolist()
    np.testing.assert_allclose(many, np.linalg.norm(a - b, axis=1), rtol=1e-15)


@pytest.mark.parametrize(
    ("spec", "field", "value"),
    [
        (Range, "max_range_m", 0.0),
        (Range, "max_range_m", -1.0),
        (Logistic, "width_m", 0.0),
        (Logistic, "d50_m", -2.0),
        (LogDistance, "d0_m", 0.0),
        (LogDistance, "shadowing_correlation", 1.0),
    ],
)
def test_bad_parameters_are_refused(spec: type, field: str, value: float) -> None:
    base = (
        {"max_range_m": 5.0}
        if spec is Range
        else {"d50_m": 5.0, "width_m": 1.0}
        if spec is Logistic
        else {}
    )
    with pytest.raises(ValueError, match=field):
        spec(**{**base, field: value})
