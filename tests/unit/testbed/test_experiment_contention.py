"""``formation experiment wireless --contention`` on a small grid: the air's losses by team
size, and the control links on the air or off it."""

from __future__ import annotations

from testbed.experiments.contention import ContentionSpec, contention_variant, run_contention


def test_a_crowded_channel_loses_states_and_the_shared_one_reports_too() -> None:
    spec = ContentionSpec(sizes=(4, 20), rates_mbps=(6.0,), seeds=(1,), epochs=4,
                          strategies=("hold",))  # fmt: skip
    r = run_contention(spec, log=lambda _: None)
    cell = {(row["case"], row["agents"]): row for row in r.rows}
    assert cell[("6 Mb/s, shared", 4.0)]["formation_delivered"] == 1.0  # few: no loss
    assert cell[("6 Mb/s, shared", 20.0)]["formation_delivered"] < 0.95  # crowded
    assert cell[("6 Mb/s, shared", 20.0)]["reports_delivered"] < 1.0  # reports on the air
    assert cell[("6 Mb/s, own", 20.0)]["reports_delivered"] == 1.0  # off it
    assert contention_variant(spec, 20, 6.0, "own").network.air.links == "formation"  # type: ignore[union-attr]
