"""The testbed's scripting API: what a researcher calls from a script or a notebook.

    import testbed

    scenario = testbed.load_scenario("scenarios/paper.toml")
    run = testbed.simulate(scenario, strategy="estimate", seed=1)
    frames = run.frames()  # the same DataFrames as testbed.load_run("runs/<id>/run.mcap")
    frames.metrics.plot(x="epoch", y="formation_error_m", logy=True)

Every name loads its module on first use: ``import testbed`` and a simulation load neither
Zenoh, the Foxglove SDK nor mcap; :func:`launch` (real processes) and the recording readers do.
``docs/api.md`` describes each name; ``formation`` (the command) is ``testbed.cli``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from formation.first_use import load_on_first_use

if TYPE_CHECKING:
    from analysis import Frames, RunData, frames, summarise
    from formation.errors import TestbedError
    from formation.scenario import Scenario
    from formation.scenario import load as load_scenario
    from recorder import load_run, read_run
    from testbed.experiments.sweep import run_sweep
    from testbed.experiments.sweep_spec import SweepSpec
    from testbed.runtime.launcher import LocalRun, RunHooks, launch
    from testbed.runtime.outcome import RunOutcome
    from testbed.sim.batch import BatchResult, run_batch
    from testbed.sim.plan import BatchPlan, plan_batch
    from testbed.sim.result import SimResult
    from testbed.sim.simulate import simulate
    from testbed.sim.team_generators import henneberg_team, rigid_team

# name → its module ("module:attribute" where it is spelt otherwise): each loads on first use.
_API: dict[str, str] = {
    "BatchPlan": "testbed.sim.plan",
    "BatchResult": "testbed.sim.batch",
    "Frames": "analysis",
    "LocalRun": "testbed.runtime.launcher",
    "RunData": "analysis",
    "RunHooks": "testbed.runtime.launcher",
    "RunOutcome": "testbed.runtime.outcome",
    "Scenario": "formation.scenario",
    "SimResult": "testbed.sim.result",
    "SweepSpec": "testbed.experiments.sweep_spec",
    "TestbedError": "formation.errors",
    "frames": "analysis",
    "henneberg_team": "testbed.sim.team_generators",
    "launch": "testbed.runtime.launcher",
    "load_run": "recorder",
    "load_scenario": "formation.scenario:load",
    "plan_batch": "testbed.sim.plan",
    "read_run": "recorder",
    "rigid_team": "testbed.sim.team_generators",
    "run_batch": "testbed.sim.batch",
    "run_sweep": "testbed.experiments.sweep",
    "simulate": "testbed.sim.simulate",
    "summarise": "analysis",
}


__getattr__ = load_on_first_use(__name__, _API)


def __dir__() -> list[str]:
    return sorted({*globals(), *_API})


__all__ = [
    "BatchPlan",
    "BatchResult",
    "Frames",
    "LocalRun",
    "RunData",
    "RunHooks",
    "RunOutcome",
    "Scenario",
    "SimResult",
    "SweepSpec",
    "TestbedError",
    "frames",
    "henneberg_team",
    "launch",
    "load_run",
    "load_scenario",
    "plan_batch",
    "read_run",
    "rigid_team",
    "run_batch",
    "run_sweep",
    "simulate",
    "summarise",
]
