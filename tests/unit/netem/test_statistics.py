"""Measured loss, bursts, state occupancy and delays of netem's link models against closed forms.

Each model runs 100,000 to 200,000 epochs with the fixed seed of the ``seed`` fixture. A measured value
passes when it lies within ``Z = 4`` standard errors of the closed form. The
standard error comes from batch means (50 batches, after a burn-in of 1,000
epochs), which accounts for the autocorrelation of Markov chains as long as a
batch (2,000 to 4,000 epochs) is much longer than the chain's mixing time (tens
of epochs here). Mean burst length is a ratio (drops / bursts), its standard
error the delta-method one over the same batches. ``test_ci_rejects_*`` show
the same intervals reject a model whose parameter is off by 10 to 20 %, so
the tests can fail.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pytest

from formation.linkmodels import (
    Bernoulli,
    Delay,
    Duplicate,
    GilbertElliott,
    LinkModelSpec,
    Markov4,
    Outage,
    Reorder,
)
from netem.links.models import (
    Schedule,
    delay_moments,
    expected_burst_length,
    expected_loss_rate,
    schedule,
    stationary_distribution,
)

Z = 4.0  # half-width of the interval in standard errors
N_BATCHES = 50
BURN_IN = 1_000

GE = GilbertElliott(p=0.05, r=0.3, **{"1-h": 0.8, "1-k": 0.02})
GILBERT = GilbertElliott(p=0.02, r=0.25)  # 1-h = 1, 1-k = 0: bursts are geometric, mean 1/r
MARKOV4 = Markov4(p13=0.02, p31=0.3, p32=0.1, p23=0.4, p14=0.01)
BERNOULLI = Bernoulli(p_loss=0.1)
BERNOULLI_CORR = Bernoulli(p_loss=0.2, correlation=0.5)


@dataclass(frozen=True)
class Check:
    quantity: str
    measured: float
    expected: float
    se: float

    @property
    def ok(self) -> bool:
        return abs(self.measured - self.expected) <= Z * self.se

    def __str__(self) -> str:
        return (
            f"{self.quantity}: measured {self.measured:.5f}, expected {self.expected:.5f}, "
            f"SE {self.se:.5f} ({(self.measured - self.expected) / self.se:+.2f} SE)"
        )


def _batches(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    n = x.shape[0] // N_BATCHES * N_BATCHES
    return np.asarray(x[:n].reshape(N_BATCHES, -1).mean(axis=1), dtype=np.float64)


def mean_check(quantity: str, x: npt.ArrayLike, expected: float) -> Check:
    """Batch-means estimate of the mean of ``x`` against ``expected``."""
    values = np.asarray(x, dtype=np.float64)
    b = _batches(values)
    return Check(quantity, float(b.mean()), expected, float(b.std(ddof=1) / math.sqrt(N_BATCHES)))


def variance_check(quantity: str, x: npt.ArrayLike, expected: float) -> Check:
    values = np.asarray(x, dtype=np.float64)
    return mean_check(quantity, (values - values.mean()) ** 2, expected)


def burst_check(dropped: npt.NDArray[np.bool_], expected: float) -> Check:
    """Mean run length of consecutive drops = drops / burst starts, as a ratio of batch sums."""
    d = dropped.astype(np.float64)
    starts = np.concatenate([d[:1], d[1:] * (1.0 - d[:-1])])
    drops_b, starts_b = _batches(d), _batches(starts)
    ratio = float(drops_b.sum() / starts_b.sum())
    resid = drops_b - ratio * starts_b
    se = math.sqrt(float(np.sum(resid**2)) / (N_BATCHES * (N_BATCHES - 1))) / starts_b.mean()
    return Check("mean burst length", ratio, expected, float(se))


def run(stack: list[LinkModelSpec], n: int, seed: int) -> Schedule:
    sched = schedule(stack, seed, 1, 2, n + BURN_IN)
    keep = slice(BURN_IN, None)
    return Schedule(
        sched.epochs[keep],
        sched.delivered[keep],
        sched.copies[keep],
        sched.delay_epochs[keep],
        sched.delay_ms[keep],
        sched.reordered[keep],
        sched.drop_model[keep],
        sched.state_codes[keep],
        sched.layer_kinds[keep],
    )


def loss_checks(stack: list[LinkModelSpec], n: int, seed: int, burst: bool = True) -> list[Check]:
    sched = run(stack, n, seed)
    dropped = ~sched.delivered
    checks = [mean_check("loss rate", dropped, expected_loss_rate(stack))]
    if burst:
        checks.append(burst_check(dropped, expected_burst_length(stack)))
    for spec in stack:
        if isinstance(spec, GilbertElliott | Markov4):
            pi = stationary_distribution(spec)
            codes = sched.state_of(spec.model)
            labels = ["good", "bad"] if isinstance(spec, GilbertElliott) else ["1", "2", "3", "4"]
            first = 0 if isinstance(spec, GilbertElliott) else 1
            for s, label in enumerate(labels):
                checks.append(mean_check(f"P(state {label})", codes == s + first, float(pi[s])))
    return checks


def delay_checks(spec: Delay, n: int, seed: int) -> list[Check]:
    sched = run([spec], n, seed)
    m = delay_moments(spec)
    checks = []
    if spec.jitter_epochs > 0:
        checks += [
            mean_check("mean delay [epochs]", sched.delay_epochs, m.mean_epochs),
            variance_check("var delay [epochs^2]", sched.delay_epochs, m.std_epochs**2),
        ]
    if spec.jitter_ms > 0:
        checks += [
            mean_check("mean delay [ms]", sched.delay_ms, m.mean_ms),
            variance_check("var delay [ms^2]", sched.delay_ms, m.std_ms**2),
        ]
    return checks


CASES: dict[str, Callable[[int], list[Check]]] = {
    "bernoulli": lambda seed: loss_checks([BERNOULLI], 100_000, seed),
    "bernoulli-correlated": lambda seed: loss_checks([BERNOULLI_CORR], 200_000, seed, burst=False),
    "gilbert-elliott": lambda seed: loss_checks([GE], 200_000, seed),
    "gilbert": lambda seed: loss_checks([GILBERT], 200_000, seed),
    "markov4": lambda seed: loss_checks([MARKOV4], 200_000, seed),
    "outage-every+bernoulli": lambda seed: loss_checks(
        [Outage(start=10, end=30, every=100), BERNOULLI], 100_000, seed, burst=False
    ),
    "ge+bernoulli": lambda seed: loss_checks([GE, Bernoulli(p_loss=0.05)], 200_000, seed),
    "delay-uniform-epochs": lambda seed: delay_checks(
        Delay(epochs=3, jitter_epochs=2), 100_000, seed
    ),
    "delay-normal-epochs": lambda seed: delay_checks(
        Delay(epochs=10, jitter_epochs=3, distribution="normal"), 100_000, seed
    ),
    "delay-uniform-ms": lambda seed: delay_checks(Delay(ms=50.0, jitter_ms=10.0), 100_000, seed),
    "delay-normal-ms": lambda seed: delay_checks(
        Delay(ms=50.0, jitter_ms=8.0, distribution="normal"), 100_000, seed
    ),
    "delay-pareto-ms": lambda seed: delay_checks(
        Delay(ms=20.0, jitter_ms=5.0, distribution="pareto"), 100_000, seed
    ),
    "delay-paretonormal-ms": lambda seed: delay_checks(
        Delay(ms=20.0, jitter_ms=5.0, distribution="paretonormal"), 100_000, seed
    ),
    "duplicate": lambda seed: [
        mean_check("P(duplicated)", run([Duplicate(p=0.05)], 100_000, seed).copies == 2, 0.05)
    ],
    "reorder-gap1": lambda seed: [
        mean_check("P(reordered)", run([Reorder(p=0.25)], 100_000, seed).reordered, 0.25)
    ],
    # gap N, probability P: cycles of N - 1 forced epochs plus a geometric wait, mean N - 1 + 1/P
    "reorder-gap3": lambda seed: [
        mean_check(
            "P(reordered)", run([Reorder(p=0.5, gap=3)], 100_000, seed).reordered, 1 / (2 + 2)
        )
    ],
}


@pytest.mark.parametrize("case", list(CASES))
def test_matches_closed_form(case: str, seed: int) -> None:
    checks = CASES[case](seed)
    assert checks
    bad = [str(c) for c in checks if not c.ok]
    assert not bad, f"{case}: " + "; ".join(bad)


def test_closed_forms_used_above_are_the_textbook_ones() -> None:
    """The expected values above, written out by hand."""
    pi_bad = GE.p / (GE.p + GE.r)
    assert expected_loss_rate(GE) == pytest.approx(pi_bad * 0.8 + (1 - pi_bad) * 0.02, abs=1e-12)
    assert expected_burst_length(GILBERT) == pytest.approx(1 / GILBERT.r, rel=1e-9)
    assert expected_burst_length(BERNOULLI) == pytest.approx(1 / 0.9, rel=1e-9)
    m = delay_moments(Delay(epochs=3, jitter_epochs=2))
    assert (m.mean_epochs, m.std_epochs**2) == pytest.approx((3.0, 2 * 3 / 3))  # j (j + 1) / 3
    m = delay_moments(Delay(ms=50.0, jitter_ms=10.0))
    assert (m.mean_ms, m.std_ms) == pytest.approx((50.0, 10 / math.sqrt(3)), rel=1e-6)
    m = delay_moments(Delay(ms=50.0, jitter_ms=8.0, distribution="normal"))
    assert (m.mean_ms, m.std_ms) == pytest.approx((50.0, 8.0), rel=1e-3)
    # pareto table: z = 4/3 (min(x, xc) - 1.5), x ~ Pareto(1, 3); E min(x, xc) = 1.5 - xc^-2 / 2,
    # E min(x, xc)^2 = 3 - 2 / xc
    xc = 1.5 + 0.75 * 32767 / 8192
    mean_x, mean_x2 = 1.5 - 0.5 / xc**2, 3 - 2 / xc
    m = delay_moments(Delay(ms=20.0, jitter_ms=5.0, distribution="pareto"))
    assert m.mean_ms == pytest.approx(20.0 + 5.0 * 4 / 3 * (mean_x - 1.5), rel=1e-4)
    assert m.std_ms == pytest.approx(5.0 * 4 / 3 * math.sqrt(mean_x2 - mean_x**2), rel=1e-3)


# a model off by 10–20 % in one parameter, and the case whose measurement must reject it
WRONG: dict[str, tuple[list[LinkModelSpec], int, list[LinkModelSpec]]] = {
    "bernoulli": ([BERNOULLI], 100_000, [Bernoulli(p_loss=0.11)]),
    "gilbert-elliott": (
        [GE],
        200_000,
        [GilbertElliott(p=0.06, r=0.3, **{"1-h": 0.8, "1-k": 0.02})],
    ),
    "gilbert": ([GILBERT], 200_000, [GilbertElliott(p=0.02, r=0.3)]),
    "markov4": ([MARKOV4], 200_000, [Markov4(p13=0.024, p31=0.3, p32=0.1, p23=0.4, p14=0.01)]),
}


@pytest.mark.parametrize("case", list(WRONG))
def test_ci_rejects_a_wrong_model(case: str, seed: int) -> None:
    stack, n, wrong = WRONG[case]
    sched = run(stack, n, seed)
    dropped = ~sched.delivered
    loss = mean_check("loss rate", dropped, expected_loss_rate(wrong))
    burst = burst_check(dropped, expected_burst_length(wrong))
    assert not (loss.ok and burst.ok), f"{case}: {loss}; {burst}"


def test_ci_rejects_a_wrong_delay(seed: int) -> None:
    sched = run([Delay(epochs=3, jitter_epochs=2)], 100_000, seed)
    wrong = delay_moments(Delay(epochs=3, jitter_epochs=3))  # variance 4 instead of 2
    assert not variance_check("var", sched.delay_epochs, wrong.std_epochs**2).ok
