"""In-process simulator throughput in agent-epochs per second for 5, 100 and 1,000 agents.

Baseline: the 5-agent paper scenario in the same run (ratios are agent-epochs/s
against it). Seed 1; the `estimate` strategy, tree estimator.

Unicycles (issue 19): the same teams with ``dynamics = "unicycle"`` (20 inner steps per
epoch), against their single-integrator run measured just before.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from formation.scenario import Scenario
from testbed.sim.simulate import simulate
from testbed.sim.team_generators import henneberg_team

ROOT = Path(__file__).resolve().parents[1]
SEED = 1


def rate(scenario: Scenario, repeats: int = 3) -> float:
    """Best of ``repeats``: agent-epochs per second."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        simulate(scenario, seed=SEED)
        best = min(best, time.perf_counter() - start)
    return scenario.n * scenario.epochs / best


def main() -> None:
    cases = [
        ("paper, 5 agents", Scenario.from_file(ROOT / "scenarios/paper.toml").with_overrides(epochs=200)),
        ("100 agents (10% loss)", henneberg_team(100, epochs=100, network={"formation_default": [{"model": "bernoulli", "p_loss": 0.1}]})),
        ("1000 agents (10% loss)", henneberg_team(1000, epochs=20, network={"formation_default": [{"model": "bernoulli", "p_loss": 0.1}]})),
    ]  # fmt: skip
    print(f"seed {SEED}; baseline: the 5-agent paper scenario, measured in this run (best of 3)")
    print(f"{'case':26} {'agent-epochs/s':>15} {'epochs/s':>10} {'ratio':>7}")
    base = None
    for name, scenario in cases:
        r = rate(scenario)
        base = base or r
        print(f"{name:26} {r:15.0f} {r / scenario.n:10.1f} {r / base:7.2f}", flush=True)
    print("unicycle against single integrator, the same team and seed (best of 3, this run)")
    print(f"{'case':26} {'single':>12} {'unicycle':>12} {'ratio':>7}")
    for name, scenario in cases[:2]:
        single = rate(scenario)
        control = {**scenario.control.model_dump(), "dynamics": "unicycle"}
        uni = rate(scenario.with_overrides(control=control))
        print(f"{name:26} {single:12.0f} {uni:12.0f} {uni / single:7.2f}", flush=True)


if __name__ == "__main__":
    main()
