"""Saturation throughput of the air model against Bianchi's analytical model and its
refinement with the standard's access after a busy period (docs/model.md §11).

At 54 Mb/s the model's mean over seeds is close enough to Bianchi's that one seed's run within
3 % is not luck. At 6 Mb/s and 50 stations the model runs about 3 % above Bianchi, as ns-3
does: its busy slots count down no backoff, which Bianchi's chain assumes they do, and the
refined chain, which writes that rule in, holds it (bench/bench_wifi.py prints the table over
seeds, bench/bench_wifi_ns3.py --saturation ns-3's).
"""

from __future__ import annotations

import pytest

from netem.links.wifi import AirConfig
from netem.links.wifi.saturation import (
    backoff_stages,
    bianchi_tau,
    bianchi_throughput_bps,
    collider_wait_slots,
    refined_p_per_attempt,
    refined_tau,
    refined_throughput_bps,
    saturated_run,
    simulated_throughput_bps,
)

PAYLOAD_BYTES = 1500
SEED = 1


def test_the_fixed_point_is_bianchis() -> None:
    # Bianchi (2000), Fig. 5's setting W = 32, m = 3: p grows with n as the figure shows
    tau, p = bianchi_tau(10, 32, 3)
    assert p == pytest.approx(1 - (1 - tau) ** 9)
    assert 0.25 < p < 0.35
    assert bianchi_tau(50, 32, 3)[1] > bianchi_tau(10, 32, 3)[1]


@pytest.mark.parametrize("rate_mbps", [6.0, 54.0])
def test_both_chains_give_a_lone_station_its_frame_and_mean_backoff(rate_mbps: float) -> None:
    # alone, a station sends a frame every T_s and (W − 1) / 2 idle slots on average
    config = AirConfig(phy="ofdm", rate_mbps=rate_mbps)
    phy, rate = config.physical, config.rate_kbps
    w, _ = backoff_stages(config)
    data = phy.airtime_ns(PAYLOAD_BYTES + config.mac_overhead_bytes, rate)
    t_s = data + phy.sifs_ns + phy.ack_ns(rate) + phy.difs_ns
    alone = 8 * PAYLOAD_BYTES / (t_s + (w - 1) / 2 * phy.slot_ns) * 1e9
    assert bianchi_throughput_bps(config, 1, PAYLOAD_BYTES) == pytest.approx(alone, rel=1e-12)
    assert refined_throughput_bps(config, 1, PAYLOAD_BYTES) == pytest.approx(alone, rel=1e-12)


@pytest.mark.parametrize(("n", "wait"), [(2, 0.0), (10, 4.5), (50, 4.5)])
def test_the_refined_fixed_point_sums_the_stages(n: int, wait: float) -> None:
    # τ = Σ p^i / Σ p^i (1 + B_i), summed stage by stage (docs/model.md §11)
    w, m = 16, 6
    tau, p = refined_tau(n, w, m, wait)
    backoff = [(w - 2) / 2] + [(2 ** min(i, m) * w - 1) / 2 + wait for i in range(1, 400)]
    attempts = sum(p**i for i in range(400))
    slots = sum(p**i * (1 + b) for i, b in enumerate(backoff))
    assert tau == pytest.approx(attempts / slots, rel=1e-9)
    assert p == pytest.approx(1 - (1 - tau) ** (n - 1))


@pytest.mark.parametrize("n", [5, 10, 20, 50])
def test_saturation_throughput_is_bianchis_within_3_percent(n: int) -> None:
    config = AirConfig(phy="ofdm", rate_mbps=54.0)
    expected = bianchi_throughput_bps(config, n, PAYLOAD_BYTES)
    measured = simulated_throughput_bps(config, n, PAYLOAD_BYTES, max(30, 2400 // n), SEED)
    assert measured == pytest.approx(expected, rel=0.03)


def test_fifty_stations_at_6_mbps_follow_the_refined_chain_not_bianchis() -> None:
    config = AirConfig(phy="ofdm", rate_mbps=6.0)
    run = saturated_run(config, 50, PAYLOAD_BYTES, 100, SEED)
    chain = bianchi_throughput_bps(config, 50, PAYLOAD_BYTES)
    refined = refined_throughput_bps(config, 50, PAYLOAD_BYTES)
    assert run.throughput_bps == pytest.approx(refined, rel=0.03)
    assert abs(run.throughput_bps / refined - 1) < abs(run.throughput_bps / chain - 1)
    # and so do the collisions: fewer than Bianchi's chain has
    w, m = backoff_stages(config)
    p_refined = refined_p_per_attempt(50, w, m, collider_wait_slots(config))
    p_chain = bianchi_tau(50, w, m)[1]
    assert abs(run.p_collision - p_refined) < abs(run.p_collision - p_chain)
