"""The realtime layout: as many agent processes as the cores afford at the period."""

from __future__ import annotations

import pytest

from testbed.runtime.process_budget import realtime_layout


@pytest.mark.parametrize(
    ("n", "period_s", "cores", "pools"),
    [
        (5, 0.05, 2, None),  # 5 processes at 20 Hz on 2 cores: one per agent
        (20, 0.05, 2, 5),  # 20 at 20 Hz: 5 pools of 4
        (100, 0.1, 2, 10),
        (20, 0.02, 2, 2),
        (20, 0.005, 1, 1),  # never fewer than one
        (20, 0.05, 8, None),
    ],
)
def test_pools_follow_cores_and_period(
    n: int, period_s: float, cores: int, pools: int | None
) -> None:
    layout = realtime_layout(n, period_s, cores)
    assert layout.pools == pools
    assert f"{cores} cores, {n} agents" in layout.why


def test_it_says_what_it_picked() -> None:
    assert realtime_layout(20, 0.05, 2).why.startswith("5 pools of up to 4 agents")
    assert realtime_layout(5, 0.05, 2).why.startswith("one process per agent")


def test_it_warns_when_netem_would_forward_more_than_it_keeps_up_with() -> None:
    assert "warning" not in realtime_layout(20, 0.05, 2, packets_per_epoch=90).why
    assert "warning" not in realtime_layout(100, 0.1, 2, packets_per_epoch=594).why
    why = realtime_layout(200, 0.1, 2, packets_per_epoch=1194).why
    assert "warning: netem would forward 11,940 packets/s, above the 8,000" in why
