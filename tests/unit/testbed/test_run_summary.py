"""``formation run``'s summary row takes its numbers from the recording as the trust gate passed
it, not from what the launcher's observer parsed off the wire (README "Analysis never trusts
the wire")."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from rich.console import Console

from analysis import summarise
from formation.body import BODY_LOST_EXIT
from formation.scenario import Scenario
from recorder import read_run
from testbed.cli.run import _print_summary, _report, headline
from testbed.runtime.launcher import RunOutcome
from testbed.runtime.observer import Verdict
from testbed.runtime.outcome import Supervision
from testbed.sim.simulate import simulate
from testkit.forgeries import forgeries
from testkit.synthetic import EPOCH_NS, RUN, write_synthetic

FINAL = ("final_formation_error_m", "final_shape_error_m")


def test_the_printed_summary_is_the_recording_s_through_the_trust_gate(
    paper: Scenario, tmp_path: Path
) -> None:
    scenario = paper.with_overrides(epochs=10)
    result = simulate(scenario, "hold")
    last = scenario.epochs
    bad = forgeries(RUN, scenario, epoch=last)  # among them agent 2 claimed at [42, 42]
    inject = [(key, data, None, last * EPOCH_NS + 50 + m) for m, (key, data) in enumerate(bad)]
    run_dir = tmp_path / "run"
    write_synthetic(run_dir / "run.mcap", result, inject=inject)
    seen = result.positions.copy()
    seen[last, 1] = 42.0  # what a reader that parses states by hand takes
    outcome = RunOutcome(
        run_id="r", run_dir=run_dir, scenario=scenario, strategy="hold", seed=scenario.seed,
        positions=seen, estimated_epochs=[], decisions=[], malformed={}, sent={}, pids=[],
        wall_s=0.0, substitutions=[],
    )  # fmt: skip
    recorded = _report(run_dir, Console(file=io.StringIO()))
    trusted = summarise(read_run(run_dir / "run.mcap"))
    got = headline(outcome, recorded)
    for name in FINAL:
        assert got[name] == trusted[name] == result.summary()[name], name
        assert got[name] != outcome.summary()[name], name  # the forged state moved it
    assert got["skipped"] == len(bad) > 0
    assert got["min_distance_m"] == trusted["safety"]["min_distance_m"]
    out = io.StringIO()
    _print_summary([outcome], Console(file=out, width=300), {"r": recorded})
    assert f"{trusted[FINAL[0]]:.4g}" in out.getvalue()
    # Without a recording (--no-record) the row is what the launcher saw.
    assert headline(outcome, None)[FINAL[0]] == outcome.summary()[FINAL[0]]
    assert np.isfinite(outcome.summary()[FINAL[0]])


def test_what_the_launcher_supervised_goes_into_the_summary_in_its_order(paper: Scenario) -> None:
    scenario = paper.with_overrides(epochs=4)
    x = simulate(scenario, "hold").positions.copy()
    x[3:, 2] = np.nan  # agent 3 lost at epoch 3
    loss = {"name": "agent-3", "pid": 7, "code": -9, "epoch": 3, "after_start_s": 0.5}
    seen = Supervision(
        deadline={"late": 2}, losses=[loss], fallbacks=3, fallback_epochs={3: 3},
        team_events=[(1.0, "{}")], priorities="netem favoured", cpu_steal=0.25,
    )  # fmt: skip
    outcome = RunOutcome(
        run_id="r", run_dir=Path("unused"), scenario=scenario, strategy="hold", seed=1,
        positions=x, estimated_epochs=[], decisions=[], malformed={}, sent={}, pids=[],
        wall_s=1.5, substitutions=[], supervision=seen,
    )  # fmt: skip
    s = outcome.summary()
    assert list(s) == [
        "run_id", "strategy", "seed", "epochs", "final_formation_error_m", "final_shape_error_m",
        "packets_sent", "packets_dropped", "dropped_links", "malformed", "mode", "deadline",
        "deadline_misses", "modelled_losses", "delivered_in_time", "robot_silent", "unaccounted",
        "deadline_miss_rate", "deadline_warning", "priorities", "cpu_steal", "wall_s", "losses",
        "team", "fallbacks",
    ]  # fmt: skip
    assert s["deadline"] == {"late": 2} and s["priorities"] == "netem favoured"
    assert s["cpu_steal"] == 0.25 and s["fallbacks"] == 3
    assert s["losses"] == [{**loss, "dropped": 0, "missed": 6}]  # 2 epochs × its 3 links
    assert s["team"]["3"] == [(0, 2)]


def test_a_pool_whose_robot_was_lost_is_summed_over_its_agents(paper: Scenario) -> None:
    # pool-2-3 stopped at epoch 3 as one of its robots' poses stopped coming: netem's
    # deliveries to both its agents from epoch 2 on were never taken (robot silent)
    scenario = paper.with_overrides(epochs=4, runtime={"mode": "realtime"})
    x = simulate(scenario.with_overrides(runtime={"mode": "lockstep"}), "hold").positions.copy()
    x[3:, 1:3] = np.nan
    loss = {"name": "pool-2-3", "pid": 7, "code": BODY_LOST_EXIT, "epoch": 3, "after_start_s": 0.5}
    decisions = [
        Verdict(source, target, "formation", k, k, verdict)
        for k in range(5)
        for source, target in ((1, 2), (4, 3), (1, 5))
        for verdict in ("pass", "drop")
    ]
    outcome = RunOutcome(
        run_id="r", run_dir=Path("unused"), scenario=scenario, strategy="hold", seed=1,
        positions=x, estimated_epochs=[], decisions=decisions, malformed={}, sent={}, pids=[],
        wall_s=1.5, substitutions=[], supervision=Supervision(deadline={"x": 0}, losses=[loss]),
    )  # fmt: skip
    # epochs 2, 3, 4 into agents 2 and 3: six packets passed, none into agent 5
    assert outcome.untaken_for_lost_robots() == 6
    assert outcome.summary()["robot_silent"] == 6
    (summed,) = outcome.summary()["losses"]
    links = scenario.directed_links
    out_of = {i: int((links[:, 0] == i).sum()) for i in (2, 3)}
    assert summed["dropped"] == 10  # its links' drops: 1->2 and 4->3, at every epoch
    assert summed["missed"] == 2 * out_of[2] + 2 * out_of[3]  # epochs 3 and 4 of each
