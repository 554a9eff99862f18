"""The compiled event loop against the model in Python (``dcf.reference_phase``): the same
decisions, causes, arrival times, attempts and first starts on random phases, and the same
received powers and chunk success rates to rounding (docs/model.md §11)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from netem.links.wifi import BROADCAST, PHYS, AirConfig, Frames, Key, PhaseOutcome, decide_phase
from netem.links.wifi.compiled_phase import _air, _arrays_of
from netem.links.wifi.compiled_reception import chunk_success as compiled_chunk
from netem.links.wifi.dcf import _power_mw, reference_phase
from netem.links.wifi.error_rate import chunk_success


def same(a: PhaseOutcome, b: PhaseOutcome) -> None:
    for name in ("delivered", "arrival_ns", "cause", "attempts", "first_start_ns"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.end_ns == b.end_ns


@st.composite
def phases(draw: st.DrawFn) -> tuple[AirConfig, np.ndarray, Frames, Key, int | None]:
    phy = draw(st.sampled_from(sorted(PHYS)))
    rate = draw(st.sampled_from(PHYS[phy].rates_kbps)) / 1000
    config = AirConfig(
        phy=phy,
        rate_mbps=rate,
        error_model=draw(st.sampled_from(["chunks", "threshold"])),
        shadowing_sigma_db=draw(st.sampled_from([0.0, 4.0])),
        retry_limit=draw(st.integers(1, 7)),
    )
    n = draw(st.integers(2, 12))
    spread = draw(st.sampled_from([5.0, 40.0, 120.0]))  # all in range .. hidden pairs
    seed = draw(st.integers(0, 2**31))
    rng = np.random.default_rng(seed)
    positions = rng.uniform(0.0, spread, (n, 2))
    m = draw(st.integers(1, 2 * n))
    sender = rng.integers(0, n, m)
    if draw(st.booleans()):
        receiver = np.full(m, BROADCAST)
    else:  # unicast, some broadcast among them
        receiver = (sender + rng.integers(1, n, m)) % n
        receiver[rng.random(m) < 0.3] = BROADCAST
    payload = rng.integers(0, 1500, m)
    ready = rng.integers(0, draw(st.sampled_from([1, 200_000, 2_000_000])), m)
    end = draw(st.sampled_from([None, 1_000_000, 3_000_000]))
    key = Key(seed, draw(st.integers(0, 1000)), draw(st.integers(0, 3)))
    return config, positions, Frames.of(sender, receiver, payload, ready), key, end


@settings(max_examples=150, deadline=None)
@given(phases())
def test_the_compiled_loop_decides_as_the_reference(
    case: tuple[AirConfig, np.ndarray, Frames, Key, int | None],
) -> None:
    config, positions, frames, key, end = case
    same(
        decide_phase(config, positions, frames, key, end),
        reference_phase(config, positions, frames, key, end),
    )


def test_a_crowded_phase_with_retries_and_hidden_pairs_decides_as_the_reference() -> None:
    rng = np.random.default_rng(3)
    n = 30
    positions = rng.uniform(0.0, 90.0, (n, 2))
    sender = np.repeat(np.arange(n), 3)
    receiver = (sender + 1 + rng.integers(0, n - 1, 3 * n)) % n
    frames = Frames.of(sender, receiver, 1500, rng.integers(0, 500_000, 3 * n))
    out = decide_phase(AirConfig(), positions, frames, Key(9, 4, 1))
    assert out.attempts.max() > 1  # retries happened
    same(out, reference_phase(AirConfig(), positions, frames, Key(9, 4, 1)))


@settings(max_examples=60, deadline=None)
@given(
    phy=st.sampled_from(sorted(PHYS)),
    snr_db=st.floats(-10.0, 30.0),
    nbits=st.integers(0, 12_000),
    data=st.data(),
)
def test_a_compiled_chunk_rate_is_the_reference_s_to_rounding(
    phy: str, snr_db: float, nbits: int, data: st.DataObject
) -> None:
    rate = data.draw(st.sampled_from(PHYS[phy].rates_kbps))
    snr = 10.0 ** (snr_db / 10.0)
    expected = chunk_success(PHYS[phy].ofdm, rate, np.array([snr]), np.array([nbits]))[0]
    got = compiled_chunk(PHYS[phy].ofdm, rate, snr, nbits)
    # a power of nbits: an ulp apart in the base is nbits ulps apart in the chance
    ulps = 4 * nbits * np.finfo(np.float64).eps * abs(expected)
    assert abs(got - expected) <= 1e-12 * max(1.0, abs(expected)) + ulps


@settings(max_examples=40, deadline=None)
@given(
    dims=st.sampled_from([2, 3]),
    n=st.integers(2, 15),
    sigma_db=st.sampled_from([0.0, 4.0]),
    seed=st.integers(0, 2**31),
)
def test_compiled_received_power_is_the_radio_s_to_rounding(
    dims: int, n: int, sigma_db: float, seed: int
) -> None:
    config = AirConfig(shadowing_sigma_db=sigma_db, reference_distance_m=2.0)
    positions = np.random.default_rng(seed).uniform(0.0, 60.0, (n, dims))
    positions[1] = positions[0] + 0.5  # closer than the reference distance
    radio, _, _ = _arrays_of(config)
    got = _air(positions, radio, seed, 7)[:n]
    expected = _power_mw(config, positions, Key(seed, 7, 0))
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=0.0)
