"""netem's link models: determinism, agreement of the three forms, stacking, run-time change."""

from __future__ import annotations

import hashlib
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import netem.links.models
from formation.errors import LinkModelError
from formation.linkmodels import (
    Bernoulli,
    Delay,
    Down,
    Duplicate,
    GilbertElliott,
    LinkModelSpec,
    Markov4,
    Outage,
    Reorder,
    Up,
    kind_code_of,
    spec_class,
    spec_classes,
)
from netem.links.layer import MODEL_NAMES
from netem.links.linkmodels import layer_of, layers
from netem.links.models import (
    LinkModel,
    Outcome,
    delivery_matrix,
    expected_burst_length,
    expected_loss_rate,
    schedule,
    stationary_distribution,
)

GE = GilbertElliott(p=0.05, r=0.3, **{"1-h": 0.8, "1-k": 0.02})
MARKOV4 = Markov4(p13=0.02, p31=0.3, p32=0.1, p23=0.4, p14=0.01)

STACKS: dict[str, list[LinkModelSpec]] = {
    "up": [Up()],
    "down": [Down()],
    "bernoulli": [Bernoulli(p_loss=0.3)],
    "bernoulli-correlated": [Bernoulli(p_loss=0.4, correlation=0.6)],
    "gilbert-elliott": [GE],
    "markov4": [MARKOV4],
    "outage-every": [Outage(start=5, end=9, every=20)],
    "delay-ms-correlated": [
        Delay(epochs=2, jitter_epochs=2, ms=30.0, jitter_ms=10.0, correlation=0.7)
    ],
    "delay-pareto": [Delay(epochs=4, jitter_epochs=2, ms=20, jitter_ms=5, distribution="pareto")],
    "everything": [
        Outage(start=100, end=140),
        GE,
        Bernoulli(p_loss=0.1),
        Delay(epochs=1, jitter_epochs=1, ms=10.0, jitter_ms=3.0, distribution="normal"),
        Delay(epochs=1, ms=5.0),
        Duplicate(p=0.2),
        Reorder(p=0.5, gap=3),
    ],
}


# ------------------------------------------------------------------------- the three forms agree


@pytest.mark.parametrize("name", list(STACKS))
def test_decide_equals_schedule(name: str, seed: int) -> None:
    stack = STACKS[name]
    n = 1_300  # crosses block boundaries of 256
    sched = schedule(stack, seed, 3, 4, n)
    model = LinkModel(stack, seed, 3, 4, block_epochs=256, cache_blocks=2)
    decided = [model.decide(k) for k in range(n)]
    assert decided == [sched.decision(k) for k in range(n)]
    assert [d.delivered for d in decided] == sched.delivered.tolist()
    assert [d.delay_epochs for d in decided] == sched.delay_epochs.tolist()
    assert [d.delay_ms for d in decided] == sched.delay_ms.tolist()
    assert [d.copies for d in decided] == sched.copies.tolist()


def test_schedule_from_a_later_start_is_a_slice(seed: int) -> None:
    stack = STACKS["everything"]
    whole = schedule(stack, seed, 1, 2, 3_000)
    part = LinkModel(stack, seed, 1, 2, block_epochs=512).schedule(1_000, start=1_700)
    for field in ("delivered", "copies", "delay_epochs", "delay_ms", "reordered", "state_codes"):
        assert np.array_equal(getattr(part, field), getattr(whole, field)[1_700:2_700]), field


def test_delivery_matrix_equals_schedule_per_link(seed: int) -> None:
    names = list(STACKS)
    # every stack on three links, so each group runs the many-links code path
    stacks = [STACKS[name] for name in names for _ in range(3)]
    links = np.array([(i % 5 + 1, (i * 7) % 11 + 1) for i in range(len(stacks))])
    n = 700
    matrix = delivery_matrix(stacks, seed, links, n)
    assert matrix.delivered.shape == (n, len(stacks))
    for col, (stack, (src, dst)) in enumerate(zip(stacks, links.tolist(), strict=True)):
        sched = schedule(stack, seed, src, dst, n)
        assert np.array_equal(matrix.delivered[:, col], sched.delivered), col
        assert np.array_equal(matrix.copies[:, col], sched.copies), col
        assert np.array_equal(matrix.delay_epochs[:, col], sched.delay_epochs), col
        assert np.array_equal(matrix.delay_ms[:, col], sched.delay_ms), col
        assert np.array_equal(matrix.reordered[:, col], sched.reordered), col


def test_delivery_matrix_checks_its_arguments(seed: int) -> None:
    with pytest.raises(LinkModelError, match=r"links has shape \(3,\); expected \(L, 2\)"):
        delivery_matrix([[Up()]], seed, [1, 2, 3], 10)
    with pytest.raises(LinkModelError, match="1 stacks for 2 links; expected one each"):
        delivery_matrix([[Up()]], seed, [[1, 2], [2, 1]], 10)
    with pytest.raises(LinkModelError, match=r"times_s has shape \(9,\); expected \(10,\)"):
        delivery_matrix([[Up()]], seed, [[1, 2]], 10, times_s=np.zeros(9))


# ------------------------------------------------------------------------- determinism


@pytest.mark.parametrize(
    "name", ["gilbert-elliott", "markov4", "bernoulli-correlated", "everything"]
)
def test_any_order_of_questions_gives_the_same_answers(name: str, seed: int) -> None:
    stack = STACKS[name]
    n = 2_000
    sequential = LinkModel(stack, seed, 1, 2, block_epochs=128)
    expected = [sequential.decide(k) for k in range(n)]
    shuffled = LinkModel(stack, seed, 1, 2, block_epochs=128, cache_blocks=1)
    order = np.random.default_rng(seed).permutation(n).tolist()
    answers = {k: shuffled.decide(k) for k in order}
    assert [answers[k] for k in range(n)] == expected
    late_first = LinkModel(stack, seed, 1, 2)
    assert late_first.decide(1_500) == expected[1_500]
    assert late_first.decide(3) == expected[3]
    assert late_first.decide(1_500) == expected[1_500]  # and again


def _digest(seed: int) -> str:
    h = hashlib.sha256()
    for name in sorted(STACKS):
        s = schedule(STACKS[name], seed, 2, 5, 3_000)
        for a in (s.delivered, s.copies, s.delay_epochs, s.delay_ms, s.reordered, s.state_codes):
            h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def test_another_process_computes_identical_bytes(seed: int) -> None:
    src = Path(netem.links.models.__file__).resolve().parents[1]
    tests = Path(__file__).resolve().parent
    code = f"import sys; sys.path[:0] = [{str(src)!r}, {str(tests)!r}]; import test_models as t; print(t._digest({seed}))"
    env = {**os.environ, "PYTHONHASHSEED": "12345"}
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        env=env,
        timeout=120,
    )
    assert out.stdout.strip() == _digest(seed)


def test_seed_and_link_change_the_decisions(seed: int) -> None:
    stack = [Bernoulli(p_loss=0.5)]
    base = schedule(stack, seed, 1, 2, 500).delivered
    assert not np.array_equal(base, schedule(stack, seed + 1, 1, 2, 500).delivered)
    assert not np.array_equal(base, schedule(stack, seed, 2, 1, 500).delivered)  # reverse direction
    assert not np.array_equal(base, schedule(stack, seed, 1, 3, 500).delivered)
    assert np.array_equal(base, schedule(stack, seed, 1, 2, 500).delivered)


def test_two_layers_of_one_kind_draw_independently(seed: int) -> None:
    one = ~schedule([Bernoulli(p_loss=0.5)], seed, 1, 2, 20_000).delivered
    two = ~schedule([Bernoulli(p_loss=0.5)] * 2, seed, 1, 2, 20_000).delivered
    assert two.mean() == pytest.approx(0.75, abs=0.02)
    assert np.all(two[one])  # the first layer's draws are the single layer's


# ------------------------------------------------------------------------- stacking


def test_outage_on_top_of_bernoulli(seed: int) -> None:
    p = 0.2
    bern = schedule([Bernoulli(p_loss=p)], seed, 1, 2, 20_000)
    stacked = schedule([Outage(start=1_000, end=3_000), Bernoulli(p_loss=p)], seed, 1, 2, 20_000)
    inside = (stacked.epochs >= 1_000) & (stacked.epochs < 3_000)
    assert not stacked.delivered[inside].any()
    assert {stacked.decision(k).model for k in range(1_000, 3_000)} == {"outage"}
    assert stacked.decision(1_500).state == "down"
    # outside the window the Bernoulli layer decides exactly as alone, at rate p
    assert np.array_equal(stacked.delivered[~inside], bern.delivered[~inside])
    rate = 1 - stacked.delivered[~inside].mean()
    assert rate == pytest.approx(p, abs=4 * math.sqrt(p * (1 - p) / (~inside).sum()))
    dropped_outside = [k for k in range(20_000) if not inside[k] and not stacked.delivered[k]]
    assert {stacked.decision(k).model for k in dropped_outside} == {"bernoulli"}


def test_first_dropping_layer_names_the_drop(seed: int) -> None:
    s = schedule([Bernoulli(p_loss=0.5), Down()], seed, 1, 2, 200)
    models = {s.decision(k).model for k in range(200)}
    assert models == {"bernoulli", "down"}


def test_verdicts(seed: int) -> None:
    assert schedule([Up()], seed, 1, 2, 5).decision(0) == Outcome(
        True, 0, 0.0, 1, "pass", "", "", False
    )
    assert schedule([Down()], seed, 1, 2, 5).decision(0) == Outcome(
        False, 0, 0.0, 0, "drop", "down", "down", False
    )
    assert schedule([Delay(epochs=2)], seed, 1, 2, 5).decision(0).verdict == "delayed"
    assert schedule([Delay(ms=2.0)], seed, 1, 2, 5).decision(0).verdict == "delayed"
    dup = schedule([Duplicate(p=0.5), Delay(epochs=1)], seed, 1, 2, 200)
    for k in range(200):
        d = dup.decision(k)
        assert d.verdict == ("duplicate" if d.copies == 2 else "delayed")
        assert d.copies in (1, 2) and d.delay_epochs == 1


def test_lockstep_uniform_jitter_stays_in_range_and_clips_at_zero(seed: int) -> None:
    s = schedule([Delay(epochs=3, jitter_epochs=2)], seed, 1, 2, 5_000)
    assert set(s.delay_epochs.tolist()) == {1, 2, 3, 4, 5}
    s = schedule([Delay(epochs=1, jitter_epochs=3)], seed, 1, 2, 5_000)
    assert set(s.delay_epochs.tolist()) == {0, 1, 2, 3, 4}
    assert (s.delay_epochs == 0).mean() == pytest.approx(3 / 7, abs=0.03)  # -3, -2, -1 clip to 0


def test_delay_correlation_correlates_successive_delays(seed: int) -> None:
    def lag1(c: float) -> float:
        ms = schedule([Delay(ms=50.0, jitter_ms=10.0, correlation=c)], seed, 1, 2, 20_000).delay_ms
        return float(np.corrcoef(ms[:-1], ms[1:])[0, 1])

    assert abs(lag1(0.0)) < 0.03
    assert lag1(0.8) > 0.6


def test_reorder_with_gap_sends_every_nth_epoch_at_once(seed: int) -> None:
    s = schedule([Delay(epochs=2), Reorder(p=1.0, gap=3)], seed, 1, 2, 30)
    assert np.flatnonzero(s.reordered).tolist() == list(range(2, 30, 3))
    assert np.all(s.delay_epochs[s.reordered] == 0)
    assert np.all(s.delay_epochs[~s.reordered] == 2)
    assert s.decision(2) == Outcome(True, 0, 0.0, 1, "pass", "", "", True)


def test_later_packets_of_an_epoch_share_the_loss_and_draw_their_own_delay(seed: int) -> None:
    stack: list[LinkModelSpec] = [
        GE,
        Delay(epochs=5, jitter_epochs=3, ms=50.0, jitter_ms=20.0),
        Duplicate(p=0.5),
    ]
    model = LinkModel(stack, seed, 1, 2)
    differs = 0
    for k in range(300):
        d0, d1 = model.decide(k), model.decide(k, seq=1)
        assert d1.delivered == d0.delivered and d1.state == d0.state
        assert model.decide(k, seq=1) == d1
        differs += d1.delay_ms != d0.delay_ms
    assert differs > 200


def test_realtime_outage_needs_the_packet_time(seed: int) -> None:
    stack: list[LinkModelSpec] = [Outage(start_s=2.0, end_s=3.5), Bernoulli(p_loss=0.1)]
    model = LinkModel(stack, seed, 1, 2)
    with pytest.raises(LinkModelError, match=r"link 1→2: stack\[0\] outage is given in seconds"):
        model.decide(4)
    times = np.arange(100) * 0.05  # a 50 ms period
    sched = model.schedule(100, times_s=times)
    decided = [model.decide(k, time_s=float(times[k])) for k in range(100)]
    assert decided == [sched.decision(k) for k in range(100)]
    window = (times >= 2.0) & (times < 3.5)
    assert not sched.delivered[window].any()
    assert {decided[k].model for k in np.flatnonzero(window)} == {"outage"}
    matrix = delivery_matrix([stack], seed, [[1, 2]], 100, times_s=times)
    assert np.array_equal(matrix.delivered[:, 0], sched.delivered)


# ------------------------------------------------------------------------- run-time change


def specs_at(model: LinkModel, epoch: int) -> tuple[LinkModelSpec, ...]:
    """The stack in force at ``epoch``: the last of ``model.timeline`` starting at or before it."""
    return next(specs for start, specs in reversed(model.timeline) if start <= epoch)


def test_replace_keeps_earlier_decisions(seed: int) -> None:
    model = LinkModel([GE], seed, 1, 2, block_epochs=64)
    before = [model.decide(k) for k in range(1_000)]
    model.replace([Down()], from_epoch=300)
    assert [model.decide(k) for k in range(300)] == before[:300]
    assert {model.decide(k).model for k in range(300, 1_000)} == {"down"}
    assert specs_at(model, 299) == (GE,) and specs_at(model, 300) == (Down(),)
    assert model.specs == (Down(),)
    assert model.timeline == ((0, (GE,)), (300, (Down(),)))


def test_replace_by_the_same_kind_carries_the_markov_state(seed: int) -> None:
    plain = schedule([GE], seed, 1, 2, 1_000)
    same = LinkModel([GE], seed, 1, 2, block_epochs=100)
    same.replace([GE], from_epoch=437)
    assert [same.decide(k) for k in range(1_000)] == [plain.decision(k) for k in range(1_000)]
    # a chain that never moves keeps whatever state it was handed at epoch 437
    frozen = LinkModel([GE], seed, 1, 2)
    frozen.replace([GilbertElliott(p=0.0, r=0.0)], from_epoch=437)
    states = {frozen.decide(k).state for k in range(437, 1_000)}
    assert states == {plain.decision(437).state}
    # the same with the other state, to be sure both are carried
    k_bad = next(k for k in range(1_000) if plain.decision(k).state == "bad")
    frozen.replace([GilbertElliott(p=0.0, r=0.0)], from_epoch=k_bad)
    assert {frozen.decide(k).state for k in range(k_bad, 1_000)} == {"bad"}


def test_replace_by_another_kind_restarts_the_chain(seed: int) -> None:
    model = LinkModel([GE], seed, 1, 2)
    k_bad = next(k for k in range(1_000) if model.decide(k).state == "bad")
    model.replace([Up()], from_epoch=k_bad)
    model.replace([GilbertElliott(p=0.0, r=0.0)], from_epoch=k_bad + 10)  # GE absent in between
    assert {model.decide(k).state for k in range(k_bad + 10, k_bad + 200)} == {"good"}
    assert model.decide(k_bad - 1).state != "" and model.decide(k_bad).state == ""


def test_replace_supersedes_later_changes(seed: int) -> None:
    model = LinkModel([Up()], seed, 1, 2)
    model.replace([Down()], from_epoch=50)
    model.replace([Bernoulli(p_loss=0.0)], from_epoch=20)
    assert all(model.decide(k).delivered for k in range(100))
    assert specs_at(model, 60) == (Bernoulli(p_loss=0.0),)


# ------------------------------------------------------------------------- closed forms


def test_stationary_distributions_have_their_closed_forms() -> None:
    assert stationary_distribution(GE) == pytest.approx([0.3 / 0.35, 0.05 / 0.35], rel=1e-12)
    m = MARKOV4
    pi = np.array([m.p31 * m.p23, m.p13 * m.p32, m.p13 * m.p23, m.p14 * m.p31 * m.p23])
    assert stationary_distribution(m) == pytest.approx(pi / pi.sum(), rel=1e-12)
    assert expected_loss_rate(m) == pytest.approx((pi[2] + pi[3]) / pi.sum(), rel=1e-12)


def test_degenerate_chains_have_the_occupancy_they_really_have() -> None:
    alternating = Markov4(p13=0.0, p14=1.0)  # 1, 4, 1, 4, ...: period 2
    assert stationary_distribution(alternating) == pytest.approx([0.5, 0, 0, 0.5])
    assert expected_burst_length(alternating) == pytest.approx(1.0)
    stuck = GilbertElliott(p=0.0, r=0.0)  # starts good and stays
    assert stationary_distribution(stuck) == pytest.approx([1.0, 0.0])


def test_loss_rate_and_bursts_of_stacks() -> None:
    assert expected_loss_rate([Up()]) == 0.0
    assert expected_loss_rate(Down()) == 1.0
    assert expected_loss_rate([Bernoulli(p_loss=0.1), Bernoulli(p_loss=0.2)]) == pytest.approx(
        1 - 0.9 * 0.8
    )
    assert expected_loss_rate(Outage(start=3, end=8, every=10)) == pytest.approx(0.5)
    assert expected_loss_rate(Outage(start=3, end=8)) == 0.0
    assert expected_loss_rate(Outage(start=3)) == 1.0
    assert expected_burst_length(Bernoulli(p_loss=0.25)) == pytest.approx(4 / 3)
    assert expected_burst_length([Down()]) == math.inf
    assert math.isnan(expected_burst_length([Up(), Delay(epochs=3)]))
    with pytest.raises(LinkModelError, match=r"stack\[0\] outage has no closed-form burst length"):
        expected_burst_length([Outage(start=1, end=4)])


def test_correlated_bernoulli_loses_less_than_p_as_in_tc() -> None:
    assert expected_loss_rate(Bernoulli(p_loss=0.2, correlation=0.0)) == pytest.approx(0.2)
    assert expected_loss_rate(Bernoulli(p_loss=0.2, correlation=0.5)) == pytest.approx(
        0.0294, abs=2e-4
    )
    # by symmetry of the stationary law around 1/2
    assert expected_loss_rate(Bernoulli(p_loss=0.5, correlation=0.5)) == pytest.approx(
        0.5, abs=1e-4
    )


@settings(max_examples=40, deadline=None)
@given(
    p=st.floats(0.001, 1.0),
    r=st.floats(0.001, 1.0),
    bad=st.floats(0.0, 1.0),
    good=st.floats(0.0, 1.0),
)
def test_gilbert_elliott_closed_forms_hold_for_any_parameters(
    p: float, r: float, bad: float, good: float
) -> None:
    spec = GilbertElliott(p=p, r=r, **{"1-h": bad, "1-k": good})
    pi = stationary_distribution(spec)
    assert pi == pytest.approx([r / (p + r), p / (p + r)], rel=1e-9, abs=1e-12)
    assert expected_loss_rate(spec) == pytest.approx(
        p / (p + r) * bad + r / (p + r) * good, rel=1e-9, abs=1e-12
    )
    if bad == 1.0 and good == 0.0:
        assert expected_burst_length(spec) == pytest.approx(1 / r, rel=1e-9)


@settings(max_examples=40, deadline=None)
@given(
    p13=st.floats(0.001, 0.5),
    p14=st.floats(0.0, 0.5),
    p31=st.floats(0.001, 0.5),
    p32=st.floats(0.0, 0.5),
    p23=st.floats(0.001, 1.0),
)
def test_markov4_occupancy_is_stationary(
    p13: float, p14: float, p31: float, p32: float, p23: float
) -> None:
    spec = Markov4(p13=p13, p14=p14, p31=p31, p32=p32, p23=p23)
    pi = stationary_distribution(spec)
    expected = np.array([p31 * p23, p13 * p32, p13 * p23, p14 * p31 * p23])
    assert pi == pytest.approx(expected / expected.sum(), rel=1e-9, abs=1e-12)


# ------------------------------------------------------------------------- input errors


def test_the_scenario_refuses_impossible_markov4_rows() -> None:
    with pytest.raises(ValueError, match=r"p13 \+ p14 = 1.2 must be <= 1"):
        Markov4(p13=0.7, p14=0.5)
    with pytest.raises(ValueError, match=r"p31 \+ p32 = 1.5 must be <= 1"):
        Markov4(p13=0.1, p31=0.9, p32=0.6)


def test_bad_inputs_are_named(seed: int) -> None:
    with pytest.raises(LinkModelError, match=r"link 1→2: stack\[0\] markov4 has p13 \+ p14 = 1.2"):
        LinkModel(
            [Markov4.model_construct(p13=0.7, p14=0.5, p31=1.0, p32=0.0, p23=1.0)], seed, 1, 2
        )
    with pytest.raises(LinkModelError, match=r"p31 \+ p32 = 1.5; expected <= 1"):
        LinkModel(
            [Markov4.model_construct(p13=0.1, p31=0.9, p32=0.6, p23=1.0, p14=0.0)], seed, 1, 2
        )
    with pytest.raises(LinkModelError, match=r"link 1→2: seed = -1; expected an integer in"):
        LinkModel([Up()], -1, 1, 2)
    with pytest.raises(LinkModelError, match=r"link 1→2: epoch = -3; expected >= 0"):
        LinkModel([Up()], seed, 1, 2).decide(-3)
    with pytest.raises(LinkModelError, match=r"times_s has shape \(4,\); expected \(5,\)"):
        LinkModel([Up()], seed, 1, 2).schedule(5, times_s=np.zeros(4))


def test_every_tag_has_a_layer_and_keeps_its_kind_code() -> None:
    # A tag's position is its kind code in every keyed draw: new models are appended.
    codes = {tag: kind_code_of(cls) for tag, cls in spec_classes().items()}
    assert sorted(codes, key=codes.__getitem__)[:12] == [
        "up",
        "down",
        "bernoulli",
        "gilbert_elliott",
        "markov4",
        "outage",
        "delay",
        "duplicate",
        "reorder",
        "range",
        "logistic",
        "log_distance",
    ]
    assert sorted(codes.values())[:12] == list(range(12))
    every = layers()
    assert all(layer_of(spec_class(tag).model_construct()) is every[tag] for tag in codes)
    LinkModel([spec_class("bernoulli").model_validate({"p_loss": 0.1})], 1, 1, 2)
    assert "bernoulli" in MODEL_NAMES
