"""A capacity queue in virtual time against its closed forms (docs/model.md §9).

Burst departures at ``k L / r``, long-run throughput at the rate, a burst's drops from
burst, limit and size, and Poisson arrivals of fixed-size packets against the M/D/1/K
blocking probability computed here from the embedded Markov chain.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from netem.links.capacity import (
    OVERSIZE,
    PASSED,
    QUEUE_FULL,
    QUEUE_LATE,
    Policy,
    QueueParams,
    QueueState,
    _serve_many,
    _serve_one,
    serve_packets,
    serve_queue,
)

L = 1000  # [B] a packet with its overhead
R = 1e6  # [bit/s]


@pytest.mark.parametrize("overhead", [0, 42])
def test_the_kth_packet_of_a_burst_leaves_at_k_l_over_r(overhead: int) -> None:
    run = serve_queue(
        QueueParams(rate_bps=R, overhead_bytes=overhead), np.zeros(10), np.full(10, L - overhead)
    )
    k = np.arange(1, 11)
    np.testing.assert_allclose(run.departure_s, k * 8 * L / R, rtol=1e-12)
    assert np.all(run.reason == PASSED)
    assert run.depth.tolist() == list(range(10))
    np.testing.assert_allclose(run.sojourn_s, run.departure_s)


@pytest.mark.parametrize("burst", [1000, 2500, 4000])
def test_a_tbf_bucket_lets_its_credit_through_then_paces_at_the_rate(burst: int) -> None:
    run = serve_queue(QueueParams(rate_bps=R, burst_bytes=burst), np.zeros(10), np.full(10, L))
    q, rem = divmod(burst, L)
    expected = np.concatenate([np.zeros(q), (np.arange(1, 11 - q) * L - rem) * 8 / R])
    np.testing.assert_allclose(run.departure_s, expected, rtol=1e-12, atol=1e-15)


def test_long_run_throughput_tends_to_the_rate() -> None:
    rng = np.random.default_rng(7)
    service = 8 * L / R
    arrivals = np.cumsum(rng.exponential(service / 2.0, 40_000))  # offered load 2
    run = serve_queue(QueueParams(rate_bps=R, limit_packets=8), arrivals, np.full(arrivals.size, L))
    sent = run.passed
    span = run.departure_s[sent].max() - arrivals[0]
    throughput = 8 * L * sent.sum() / span
    assert throughput == pytest.approx(R, rel=0.002)
    assert (~sent).mean() == pytest.approx(0.5, abs=0.02)  # what exceeds the rate is dropped


@pytest.mark.parametrize(
    ("n", "burst", "limit_packets", "limit_bytes", "size"),
    [
        (20, 0, 5, None, 1000),
        (20, 3000, 5, None, 1000),
        (20, 3500, 4, None, 700),
        (20, 0, None, 4500, 1000),
        (20, 2000, None, 4500, 1000),
        (3, 2000, 10, None, 1000),
    ],
)
def test_a_bursts_drops_follow_from_burst_limit_and_size(
    n: int, burst: int, limit_packets: int | None, limit_bytes: int | None, size: int
) -> None:
    params = QueueParams(
        rate_bps=R, burst_bytes=burst, limit_packets=limit_packets, limit_bytes=limit_bytes
    )
    run = serve_queue(params, np.zeros(n), np.full(n, size))
    through = burst // size  # leave at once on the bucket's credit, never wait
    room = min(limit_packets or n, (limit_bytes or n * size) // size)
    kept = min(n, through + room)
    assert (run.reason == QUEUE_FULL).sum() == n - kept
    assert np.all(run.reason[:kept] == PASSED) and np.all(run.reason[kept:] == QUEUE_FULL)
    assert np.all(np.isnan(run.departure_s[kept:]))


def test_oldest_keeps_the_freshest_and_the_packet_on_the_wire() -> None:
    params = QueueParams(rate_bps=R, limit_packets=3, policy="oldest")
    run = serve_queue(params, np.zeros(10), np.full(10, L))
    # packet 0 is on the wire from 0; each newer one pushes out the oldest behind it
    assert run.passed.nonzero()[0].tolist() == [0, 8, 9]
    np.testing.assert_allclose(run.departure_s[[0, 8, 9]], np.array([1, 2, 3]) * 8 * L / R)
    tbf = serve_queue(
        QueueParams(rate_bps=R, burst_bytes=L, limit_packets=2, policy="oldest"),
        np.zeros(10),
        np.full(10, L),
    )
    assert tbf.passed.nonzero()[0].tolist() == [0, 8, 9]  # 0 left on its credit


def test_a_packet_leaving_after_its_deadline_is_late_and_still_took_the_link() -> None:
    deadline = 3.5 * 8 * L / R
    run = serve_queue(QueueParams(rate_bps=R), np.zeros(6), np.full(6, L), deadline_s=deadline)
    assert run.reason.tolist() == [PASSED] * 3 + [QUEUE_LATE] * 3
    np.testing.assert_allclose(run.departure_s, np.arange(1, 7) * 8 * L / R)


def test_a_packet_larger_than_the_bucket_is_dropped_as_tbf_does() -> None:
    run = serve_queue(QueueParams(rate_bps=R, burst_bytes=1500), np.zeros(3), [1000, 1600, 1000])
    assert run.reason.tolist() == [PASSED, OVERSIZE, PASSED]


@settings(max_examples=60, deadline=None)
@given(
    gaps=st.lists(st.floats(0.0, 0.02), min_size=2, max_size=40),
    sizes=st.lists(st.integers(40, 1500), min_size=40, max_size=40),
    cut=st.integers(1, 39),
    burst=st.sampled_from([0, 1500, 4000]),
    limit=st.sampled_from([None, 1, 3, 8]),
)
def test_a_tail_queue_split_across_calls_serves_as_one_call(
    gaps: list[float], sizes: list[int], cut: int, burst: int, limit: int | None
) -> None:
    arrivals = np.cumsum(gaps)
    n = arrivals.size
    cut = min(cut, n - 1)
    size = np.array(sizes[:n])
    params = QueueParams(rate_bps=R, burst_bytes=burst, limit_packets=limit)
    whole = serve_queue(params, arrivals, size)
    first = serve_queue(params, arrivals[:cut], size[:cut])
    second = serve_queue(params, arrivals[cut:], size[cut:], state=first.state)
    np.testing.assert_array_equal(np.concatenate([first.reason, second.reason]), whole.reason)
    np.testing.assert_array_equal(
        np.concatenate([first.departure_s, second.departure_s]), whole.departure_s
    )
    np.testing.assert_array_equal(np.concatenate([first.depth, second.depth]), whole.depth)
    left = whole.departure_s[whole.passed]
    assert np.all(np.diff(left) >= 0.0)  # FIFO


def md1k_blocking(rho: float, k: int) -> float:
    """P(an arrival finds K in the system) of M/D/1/K, from the chain embedded at departures.

    ``a_j`` = P(j Poisson arrivals in one service) = e^{-ρ} ρ^j / j!; a departure leaves
    ``i`` behind (``0 ≤ i < K``); from ``i ≥ 1`` the next leaves ``min(i − 1 + j, K − 1)``,
    from 0 ``min(j, K − 1)``. With its stationary ``π``, ``P_K = 1 − 1 / (π_0 + ρ)``
    (Gross and Harris, *Fundamentals of Queueing Theory*, M/G/1/K).
    """
    a = np.array([math.exp(-rho) * rho**j / math.factorial(j) for j in range(k)])
    p = np.zeros((k, k))
    for i in range(k):
        base = max(i - 1, 0)
        for j in range(k):
            if base + j < k - 1:
                p[i, base + j] += a[j]
        p[i, k - 1] += 1.0 - p[i].sum()
    w, v = np.linalg.eig(p.T)
    pi = np.real(v[:, np.argmin(np.abs(w - 1.0))])
    pi /= pi.sum()
    return 1.0 - 1.0 / (pi[0] + rho)


@pytest.mark.parametrize(("rho", "k"), [(0.5, 2), (0.8, 4), (1.0, 5), (1.5, 3)])
def test_poisson_arrivals_match_md1k_blocking(rho: float, k: int) -> None:
    rng = np.random.default_rng(2029)
    service = 8 * L / R
    batches, per_batch = 30, 4000
    arrivals = np.cumsum(rng.exponential(service / rho, batches * per_batch))
    run = serve_queue(QueueParams(rate_bps=R, limit_packets=k), arrivals, np.full(arrivals.size, L))
    blocked = (run.reason == QUEUE_FULL).reshape(batches, per_batch).mean(axis=1)
    half = 4.0 * blocked.std(ddof=1) / math.sqrt(batches)  # batch means: ±4 standard errors
    expected = md1k_blocking(rho, k)
    assert abs(blocked.mean() - expected) <= half, (blocked.mean(), expected, half)
    assert half < 0.15 * expected  # the interval is tight enough to tell a wrong model


def test_md1k_blocking_of_one_place_is_erlang_b_like() -> None:
    # K = 1: M/D/1/1 blocks with ρ / (1 + ρ) (busy fraction, no waiting room)
    assert md1k_blocking(0.7, 1) == pytest.approx(0.7 / 1.7)


def test_the_state_carries_the_bucket_and_the_backlog() -> None:
    params = QueueParams(rate_bps=R, burst_bytes=2 * L, limit_packets=2)
    first = serve_queue(params, np.zeros(4), np.full(4, L))
    assert first.passed.tolist() == [True, True, True, True]
    assert first.state.backlog_bytes == (L, L) and first.state.tokens_bytes == pytest.approx(0.0)
    second = serve_queue(params, [1e-3], [L], state=first.state)
    assert second.depth.tolist() == [2] and second.reason.tolist() == [QUEUE_FULL]
    assert QueueState().backlog_s == ()


@pytest.mark.parametrize(
    ("field", "value", "pattern"),
    [
        ("rate_bps", 0.0, r"rate_bps = 0\.0; expected > 0"),
        ("limit_packets", 0, r"limit_packets = 0; expected >= 1 or None"),
    ],
)
def test_bad_parameters_are_refused(field: str, value: float, pattern: str) -> None:
    kwargs: dict[str, float] = {"rate_bps": R, field: value}
    with pytest.raises(ValueError, match=pattern):
        QueueParams(**kwargs)  # type: ignore[arg-type]


@settings(max_examples=150, deadline=None)
@given(
    arrival=st.floats(0.0, 0.01),
    size=st.integers(1, 3000),
    burst=st.sampled_from([0, 1500, 4000]),
    limit=st.sampled_from([(None, None), (1, None), (None, 1000), (None, 5000)]),
    warm=st.booleans(),
)
def test_one_packet_into_an_empty_queue_takes_the_general_paths_numbers(
    arrival: float, size: int, burst: int, limit: tuple[int | None, int | None], warm: bool
) -> None:
    params = QueueParams(
        rate_bps=R, burst_bytes=burst, limit_packets=limit[0], limit_bytes=limit[1]
    )
    state = QueueState()
    if warm:  # a used bucket, its backlog gone
        used = serve_packets(QueueParams(rate_bps=R, burst_bytes=burst), [0.0], [500]).state
        state = QueueState(used.clock_s, used.tokens_bytes)
    due = [0.004]
    assert _serve_one(params, arrival, size, due, state) == _serve_many(
        params, [arrival], [size], due, state
    )


@settings(max_examples=200, deadline=None)
@given(
    sizes=st.lists(st.integers(0, 400), min_size=2, max_size=10),
    limit_packets=st.one_of(st.none(), st.integers(1, 12)),
    limit_bytes=st.one_of(st.none(), st.integers(1, 3000)),
    policy=st.sampled_from(["tail", "oldest"]),
    at=st.sampled_from([0.0, 0.2, 1e7]),
    before=st.lists(st.integers(50, 400), max_size=3),
    due_s=st.floats(0.0, 0.5),
)
def test_a_burst_into_an_empty_queue_is_the_general_case(
    sizes: list[int],
    limit_packets: int | None,
    limit_bytes: int | None,
    policy: Policy,
    at: float,
    before: list[int],
    due_s: float,
) -> None:
    params = QueueParams(rate_bps=R, limit_packets=limit_packets, limit_bytes=limit_bytes,
                         policy=policy)  # fmt: skip
    # an earlier call's packets, gone by the burst or not
    state = serve_packets(params, [at - 0.5] * len(before), before).state if before else None
    deadlines = [at + due_s] * len(sizes)
    got = serve_packets(params, [at] * len(sizes), sizes, deadlines, state)
    start = state or QueueState()
    if start.backlog_s and start.backlog_s[-1] <= at:
        start = QueueState(start.clock_s, start.tokens_bytes)
    assert got == _serve_many(params, [at] * len(sizes), sizes, deadlines, start)


def test_oldest_pushing_out_the_head_sends_the_next_no_earlier_than_the_push_out() -> None:
    # 10,000 B/s, a 6,000 B bucket: 0 empties it, 1 waits for its tokens until 0.6 s, 2 waits
    # behind it; 3 comes at 0.5 s and pushes 1 out: tbf sends 2 then, not at 0.2 s when the
    # bucket held its size (while 1 was still the head)
    params = QueueParams(rate_bps=80_000, burst_bytes=6000, limit_packets=2, policy="oldest")
    run = serve_queue(params, [0.0, 0.0, 0.0, 0.5], [6000, 6000, 2000, 1000])
    assert run.reason.tolist() == [PASSED, QUEUE_FULL, PASSED, PASSED]
    np.testing.assert_allclose(run.departure_s[[0, 2, 3]], [0.0, 0.5, 0.5])
