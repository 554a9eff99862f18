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

import importlib
from typing import TYPE_CHECKING, Any

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

# name → (module, attribute): each loads on first use.
_API: dict[str, tuple[str, str]] = {
    "BatchPlan": ("testbed.sim.plan", "BatchPlan"),
    "BatchResult": ("testbed.sim.batch", "BatchResult"),
    "Frames": ("analysis", "Frames"),
    "LocalRun": ("testbed.runtime.launcher", "LocalRun"),
    "RunData": ("analysis", "RunData"),
    "RunHooks": ("testbed.runtime.launcher", "RunHooks"),
    "RunOutcome": ("testbed.runtime.outcome", "RunOutcome"),
    "Scenario": ("formation.scenario", "Scenario"),
    "SimResult": ("testbed.sim.result", "SimResult"),
    "SweepSpec": ("testbed.experiments.sweep_spec", "SweepSpec"),
    "TestbedError": ("formation.errors", "TestbedError"),
    "frames": ("analysis", "frames"),
    "henneberg_team": ("testbed.sim.team_generators", "henneberg_team"),
    "launch": ("testbed.runtime.launcher", "launch"),
    "load_run": ("recorder", "load_run"),
    "load_scenario": ("formation.scenario", "load"),
    "plan_batch": ("testbed.sim.plan", "plan_batch"),
    "read_run": ("recorder", "read_run"),
    "rigid_team": ("testbed.sim.team_generators", "rigid_team"),
    "run_batch": ("testbed.sim.batch", "run_batch"),
    "run_sweep": ("testbed.experiments.sweep", "run_sweep"),
    "simulate": ("testbed.sim.simulate", "simulate"),
    "summarise": ("analysis", "summarise"),
}


def __getattr__(name: str) -> Any:
    if name in _API:
        module, attribute = _API[name]
        value = getattr(importlib.import_module(module), attribute)
        globals()[name] = value  # the next look-up is a plain attribute
        return value
    raise AttributeError(f"module 'testbed' has no attribute {name!r}")


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
