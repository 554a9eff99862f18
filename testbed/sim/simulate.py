"""The in-process simulator: the model of docs/model.md epoch by epoch, in one process, no Zenoh.

One run is a batch of one seed (``testbed.sim.batch``), so it composes the same cores the
services run through the one epoch loop: netem's decisions from ``netem.links.matrix.delivery_plan``
(planned by ``testbed.sim.plan``) and its link lengths from ``netem.links.matrix.link_lengths``
(``testbed.sim.ranged``), ``agent.epoch`` and ``leader.epoch``; a distributed lockstep run
with the same scenario and seed gives the same numbers.
"""

from __future__ import annotations

from formation.scenario import Scenario, StrategyName
from testbed.sim.batch import run_batch
from testbed.sim.plan import plan_batch
from testbed.sim.result import SimResult


def simulate(
    scenario: Scenario,
    strategy: StrategyName | None = None,
    seed: int | None = None,
    epochs: int | None = None,
) -> SimResult:
    """Run ``scenario`` in one process.

    Parameters
    ----------
    scenario : the validated scenario
    strategy : overrides ``scenario.strategy.name``
    seed : overrides ``scenario.seed``
    epochs : overrides ``scenario.epochs``
    """
    plan = plan_batch(scenario, [scenario.seed if seed is None else seed], epochs)
    return run_batch(plan, strategy or scenario.strategy.name).member(0)


__all__ = ["SimResult", "simulate"]
