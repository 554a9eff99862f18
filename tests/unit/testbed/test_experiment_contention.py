"""``formation experiment wireless --contention`` on a small grid: the air's losses by team
size, and the estimation traffic on the states' channel, on its own, or off the air."""

from __future__ import annotations

import numpy as np

from testbed.experiments.contention import (
    ContentionSpec,
    _sizes_where,
    answer,
    contention_variant,
    run_contention,
)


def test_the_estimation_traffic_costs_the_states_on_their_channel_and_not_off_it() -> None:
    spec = ContentionSpec(sizes=(4, 20), rates_mbps=(6.0,), seeds=(1,), epochs=4,
                          strategies=("hold", "estimate"))  # fmt: skip
    r = run_contention(spec, log=lambda _: None)
    cell = {(row["case"], row["strategy"], row["agents"]): row for row in r.rows}
    assert cell[("6 Mb/s, shared", "estimate", 4.0)]["formation_delivered"] == 1.0  # few: no loss
    shared, own, off = (cell[(f"6 Mb/s, {c}", "estimate", 20.0)] for c in ("shared", "own", "off"))
    assert shared["formation_delivered"] < own["formation_delivered"]  # reports meet states
    assert own["formation_delivered"] == off["formation_delivered"] < 0.95  # crowded anyway
    assert shared["reports_delivered"] < 1.0 and own["reports_delivered"] < 1.0
    assert off["reports_delivered"] == 1.0
    # hold sends nothing on the air but its states: the same runs in every case
    assert len({cell[(f"6 Mb/s, {c}", "hold", 20.0)]["final_error_m"] for c in spec.channels}) == 1
    assert contention_variant(spec, 20, 6.0, "off").network.air.links == "formation"  # type: ignore[union-attr]
    assert answer(r).startswith("**Does the estimation traffic cost `estimate` its advantage?**")


def test_a_cost_that_comes_and_goes_names_its_sizes_instead_of_a_threshold() -> None:
    points = np.array([5.0, 10.0, 15.0, 20.0])
    assert _sizes_where(points, np.array([False] * 4)) == "at no size"
    assert _sizes_where(points, np.array([False, True, True, True])) == "from 10 agents"
    assert _sizes_where(points, np.array([False, True, True, False])) == "at 10, 15 agents only"
